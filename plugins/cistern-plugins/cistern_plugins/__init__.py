"""The built-in pipeline stages of cistern-archive (import name ``cistern_plugins``).

They register through the same entry-point groups a third-party package uses (see ``pyproject.toml``).
"""
