"""``python -m cistern_archive`` runs the command-line app."""

from cistern_archive.cli import main

if __name__ == "__main__":
    main()
