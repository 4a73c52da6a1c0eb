"""Error types shared by every stage.

Each error names *where* the problem is (a file and line, a byte offset, a record, a packet) so that a
user can go straight to it.
"""

from __future__ import annotations


class CisternError(Exception):
    """Base class of every error this package raises on purpose."""


class CatalogError(CisternError):
    """A site record is malformed; ``problems`` holds ``file:line: field: message`` strings."""

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


class ReaderError(CisternError):
    """A recording cannot be read.

    Parameters
    ----------
    path : str
        The file being read.
    message : str
        What is wrong.
    offset : int, optional
        Byte offset of the bad data.
    record : int, optional
        Index of the bad record or packet.
    """

    def __init__(self, path: str, message: str, *, offset: int | None = None, record: int | None = None):
        self.path = str(path)
        self.offset = offset
        self.record = record
        where = self.path
        if record is not None:
            where += f": record {record}"
        if offset is not None:
            where += f": byte offset {offset}"
        super().__init__(f"{where}: {message}")


class EnvironmentProblem(CisternError):
    """The machine refused an operation: a full or read-only disk, a damaged archive index.

    Not the input's fault: the command exits 3 with one line naming the file and the problem, and
    nothing already stored is changed.
    """


class PluginError(CisternError):
    """A plugin cannot be found, loaded, or does not honour its stage's contract."""


class StageError(CisternError):
    """A pipeline stage failed on a given input.

    Parameters
    ----------
    stage : str
        ``load``, ``segment``, ``match``, ``localize``, ``map``, ``compare`` or ``report``.
    input : str
        The input that caused the failure (a scan file, a pair ``i->j``, …).
    message : str
        What went wrong.
    """

    def __init__(self, stage: str, input: str, message: str):
        self.stage = stage
        self.input = input
        self.message = message
        super().__init__(f"{stage} failed on {input}: {message}")


def describe_os_error(exc: OSError) -> str:
    """``FILE: problem`` for an operating-system error: one line, no traceback."""
    problem = exc.strerror or str(exc)
    return f"{exc.filename}: {problem}" if exc.filename is not None else problem
