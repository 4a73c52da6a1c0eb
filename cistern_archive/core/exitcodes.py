"""The command line's exit codes, shared by the commands and by the services that report to them."""

EXIT_OK = 0
"""Everything asked for was done."""
EXIT_SITES_FAILED = 1
"""The run finished, but some sites (or files) are ``partial`` or ``failed``; each is listed with why."""
EXIT_USAGE = 2
"""Bad usage, an invalid catalog or an environment problem: nothing was built."""
EXIT_INTERNAL = 3
"""A bug: an unexpected error, reported in one line with the log that holds its traceback."""
EXIT_INTERRUPTED = 130
"""Interrupted (Ctrl-C); whatever was published before stays published."""
