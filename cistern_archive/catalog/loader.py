"""Load and validate site records with ``file:line: field: message`` errors.

YAML is composed into a node tree first, so every value keeps its line; pydantic's error locations are
then mapped back onto those lines.

Records come from people and field laptops, so the loader bounds what a file may cost before it is
composed: at most :data:`MAX_RECORD_BYTES`, :data:`MAX_DEPTH` levels of nesting, :data:`MAX_ALIASES`
aliases and :data:`MAX_NODES` values once aliases are expanded (a few hundred bytes of nested aliases
would otherwise expand to billions of values). Every refusal is a :class:`CatalogError` with
``file:line``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from cistern_archive.catalog.models import SiteRecord
from cistern_archive.core.errors import CatalogError

RECORD_SUFFIXES = (".yaml", ".yml")
MAX_RECORD_BYTES = 1 << 20
"""A site record is a few kilobytes; anything over 1 MiB is refused unread."""
MAX_DEPTH = 32
MAX_ALIASES = 100
MAX_NODES = 100_000


SURVEY_INPUTS = "survey/"
"""Prefix of the input names of a survey record's files (they are archived and exported under it)."""


@dataclass(frozen=True)
class LoadedRecord:
    """A validated record and where it came from."""

    record: SiteRecord
    path: Path
    root: Path
    lines: dict[tuple[Any, ...], int]

    def resolve(self, relative: str) -> Path:
        """Absolute path of a file the record references (already checked to stay under the root)."""
        return (self.root / relative).resolve()

    def survey_root(self) -> Path:
        """The survey's data folder (absolute, or relative to the catalog root; it may lie outside)."""
        if self.record.survey is None:
            raise ValueError(f"{self.path}: the record has no survey")
        return (self.root / Path(self.record.survey.data).expanduser()).resolve()

    def input_path(self, name: str) -> Path:
        """The file an input name stands for: ``survey/<path inside the survey's data folder>`` for a
        survey record, else a path relative to the catalog root (:meth:`resolve`)."""
        if self.record.survey is not None and name.startswith(SURVEY_INPUTS):
            return self.survey_root() / name[len(SURVEY_INPUTS):]
        return self.resolve(name)

    def line_of(self, *loc: Any) -> int:
        return _nearest_line(self.lines, tuple(loc))


class _Refused(Exception):
    """A node of the record that cannot be turned into a value: (line, message)."""

    def __init__(self, line: int, message: str):
        super().__init__(message)
        self.line = line


class _Budget:
    """Counts the values constructed so far (aliases expand to copies of their anchor)."""

    def __init__(self) -> None:
        self.nodes = 0

    def spend(self, node: yaml.Node) -> None:
        self.nodes += 1
        if self.nodes > MAX_NODES:
            raise _Refused(node.start_mark.line + 1, f"more than {MAX_NODES} values once aliases are expanded")


def _construct(node: yaml.Node, loc: tuple[Any, ...], lines: dict[tuple[Any, ...], int],
               budget: _Budget) -> Any:
    budget.spend(node)
    lines[loc] = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = _key(key_node)
            out[key] = _construct(value_node, loc + (key,), lines, budget)
            lines[loc + (key,)] = key_node.start_mark.line + 1
        return out
    if isinstance(node, yaml.SequenceNode):
        return [_construct(item, loc + (k,), lines, budget) for k, item in enumerate(node.value)]
    return _scalar(node)


def _key(node: yaml.Node) -> Any:
    if not isinstance(node, yaml.ScalarNode):
        raise _Refused(node.start_mark.line + 1, "a mapping key must be a plain value, not a list or mapping")
    key = _scalar(node)
    try:
        hash(key)
    except TypeError:
        raise _Refused(node.start_mark.line + 1, f"mapping key {node.value!r} cannot be a key") from None
    return key


def _scalar(node: yaml.Node) -> Any:
    loader = yaml.SafeLoader("")
    try:
        return loader.construct_object(node, deep=True)
    except Exception as exc:  # noqa: BLE001 - PyYAML's constructors fail on odd scalars in many ways
        # (``!!int ''`` raises IndexError, a bad date ValueError, an unknown tag ConstructorError)
        problem = getattr(exc, "problem", None) or str(exc) or type(exc).__name__
        raise _Refused(node.start_mark.line + 1, f"bad value {node.value!r}: {problem}"[:300]) from None
    finally:
        loader.dispose()


def _check_shape(text: str) -> None:
    """Walk the YAML event stream (no recursion, no expansion) and refuse deep nesting and alias floods.

    Raises
    ------
    _Refused
        At the line of the first event over a limit.
    """
    depth = aliases = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_DEPTH:
                raise _Refused(event.start_mark.line + 1, f"nested more than {MAX_DEPTH} levels deep")
        elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
        elif isinstance(event, yaml.AliasEvent):
            aliases += 1
            if aliases > MAX_ALIASES:
                raise _Refused(event.start_mark.line + 1, f"more than {MAX_ALIASES} aliases (*name)")


def _nearest_line(lines: dict[tuple[Any, ...], int], loc: tuple[Any, ...]) -> int:
    while loc and loc not in lines:
        loc = loc[:-1]
    return lines.get(loc, 1)


def parse_yaml(path: Path) -> tuple[Any, dict[tuple[Any, ...], int]]:
    """Parse a YAML file keeping the line of every value.

    Raises
    ------
    CatalogError
        With ``file:line: yaml: message`` when the YAML is malformed.
    """
    text = _read_text(path)
    lines: dict[tuple[Any, ...], int] = {}
    try:
        _check_shape(text)
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        if node is None:
            return None, lines
        return _construct(node, (), lines, _Budget()), lines
    except _Refused as exc:
        raise CatalogError([f"{path}:{exc.line}: yaml: {exc}"]) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else 1
        problem = getattr(exc, "problem", None) or str(exc)
        raise CatalogError([f"{path}:{line}: yaml: {problem}"]) from None


def _read_text(path: Path) -> str:
    """The record's text, refusing files over :data:`MAX_RECORD_BYTES` before reading them."""
    try:
        with open(path, "rb") as handle:
            raw = handle.read(MAX_RECORD_BYTES + 1)
    except OSError as exc:
        raise CatalogError([f"{path}:1: (record): cannot be read: {exc.strerror or exc}"]) from None
    if len(raw) > MAX_RECORD_BYTES:
        raise CatalogError([f"{path}:1: (record): larger than {MAX_RECORD_BYTES} bytes; "
                            "a site record is a few kilobytes"])
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise CatalogError([f"{path}:{line}: (record): cannot be read: not UTF-8 text: {exc.reason}"]) from None
    return text


def format_loc(loc: Iterable[Any]) -> str:
    parts: list[str] = []
    for item in loc:
        if isinstance(item, int):
            parts.append(f"[{item}]")
        else:
            parts.append(("." if parts else "") + str(item))
    return "".join(parts) or "(record)"


def validation_problems(path: Path, error: ValidationError, lines: dict[tuple[Any, ...], int]) -> list[str]:
    """Turn a pydantic error into ``file:line: field: message`` strings."""
    problems = []
    for item in error.errors():
        loc = tuple(item["loc"])
        message = item["msg"]
        if item["type"] == "extra_forbidden":
            message = "unknown field"
        problems.append(f"{path}:{_nearest_line(lines, loc)}: {format_loc(loc)}: {message}")
    return problems


def load_record(path: Path, root: Path) -> LoadedRecord:
    """Load one site record and validate its schema (not yet its files or plugins).

    A record that is a symbolic link resolving outside ``root`` is refused: the archive names every
    input by its path inside the catalog.
    """
    if not Path(path).resolve().is_relative_to(Path(root).resolve()):
        raise CatalogError([f"{path}:1: (record): resolves to {Path(path).resolve()}, outside the catalog root "
                            f"{Path(root).resolve()} (symbolic link?)"])
    data, lines = parse_yaml(path)
    if not isinstance(data, dict):
        raise CatalogError([f"{path}:1: (record): expected a mapping of fields, got {type(data).__name__}"])
    try:
        record = SiteRecord.model_validate(data)
    except ValidationError as exc:
        raise CatalogError(validation_problems(path, exc, lines)) from None
    return LoadedRecord(record=record, path=path, root=root.resolve(), lines=lines)


def record_paths(catalog: Path) -> list[Path]:
    """Every site record under ``catalog`` (``*.yaml``/``*.yml`` in the root or ``sites/``), sorted."""
    found: list[Path] = []
    for folder in (catalog, catalog / "sites"):
        if folder.is_dir():
            found.extend(p for p in folder.iterdir() if p.suffix in RECORD_SUFFIXES and p.is_file())
    return sorted(found)
