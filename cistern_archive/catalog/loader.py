"""Load and validate site records with ``file:line: field: message`` errors.

YAML is composed into a node tree first, so every value keeps its line; pydantic's error locations are
then mapped back onto those lines.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from cistern_archive.catalog.models import SiteRecord
from cistern_archive.errors import CatalogError

RECORD_SUFFIXES = (".yaml", ".yml")


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

    def line_of(self, *loc: Any) -> int:
        return _nearest_line(self.lines, tuple(loc))


def _construct(node: yaml.Node, loc: tuple[Any, ...], lines: dict[tuple[Any, ...], int]) -> Any:
    lines[loc] = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = _scalar(key_node)
            out[key] = _construct(value_node, loc + (key,), lines)
            lines[loc + (key,)] = key_node.start_mark.line + 1
        return out
    if isinstance(node, yaml.SequenceNode):
        return [_construct(item, loc + (k,), lines) for k, item in enumerate(node.value)]
    return _scalar(node)


def _scalar(node: yaml.Node) -> Any:
    loader = yaml.SafeLoader("")
    try:
        return loader.construct_object(node, deep=True)
    finally:
        loader.dispose()


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
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CatalogError([f"{path}:1: (record): cannot be read: {exc}"]) from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else 1
        problem = getattr(exc, "problem", None) or str(exc)
        raise CatalogError([f"{path}:{line}: yaml: {problem}"]) from None
    lines: dict[tuple[Any, ...], int] = {}
    if node is None:
        return None, lines
    return _construct(node, (), lines), lines


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
    """Load one site record and validate its schema (not yet its files or plugins)."""
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
