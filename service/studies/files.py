"""The one reader of study files and study text: YAML (safe loading) or JSON.

Every way a study definition comes in goes through here: ``impactcell run`` and
:func:`service.studies.schema.load_study` (a file), the nightly suite (a folder of files), and
``POST /studies`` (a request body, whose content type says which format it is).

A study file may name a table file (``physical.base_amplitude_table: amplitudes.csv``, relative
to the study file): :func:`read_study_file` reads it and puts its rows in the definition
(:func:`read_amplitude_table`), so that the study id hashes the table's content, not its name.
Text (a request body) never opens files: a name there is refused by validation.

Hostile text is refused here, as a :class:`StudyFileError`, before it can cost anything:
nesting deeper than :data:`MAX_DEPTH` (a study is four levels deep; 100,000 would exhaust the
parser's recursion) is found by a scan of the text, and integer literals longer than
:data:`MAX_INT_DIGITS` digits are never converted (Python's ``int`` takes quadratic time for
them) but kept as :class:`HugeInteger`, which validation refuses naming the field.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import os
import re
from pathlib import Path
from typing import Any, Literal

import numpy as np

__all__ = [
    "MAX_DEPTH",
    "MAX_INT_DIGITS",
    "STUDY_SUFFIXES",
    "HugeInteger",
    "StudyFileError",
    "file_format",
    "nul_paths",
    "parse_study_text",
    "read_amplitude_table",
    "read_study_file",
]

#: How deeply lists and mappings may nest. A study is at most four levels deep
#: (``regression.tolerances.theta_eff.abs``); 32 leaves room and stays far below the
#: recursion of the parsers and of validation.
MAX_DEPTH = 32

#: The longest integer literal read as a number; longer ones are :class:`HugeInteger`. Every
#: value a study takes is far below 10**400 (1e308 is the largest float).
MAX_INT_DIGITS = 400

#: Suffixes of study files (``.json`` is JSON, the others YAML).
STUDY_SUFFIXES = (".yaml", ".yml", ".json")

Format = Literal["json", "yaml"]


class StudyFileError(ValueError):
    """Study text that cannot be read or parsed; ``cause`` is the underlying error."""

    def __init__(self, message: str, cause: BaseException) -> None:
        super().__init__(message)
        self.cause = cause


class HugeInteger(float):
    """An integer literal too long to read (more than :data:`MAX_INT_DIGITS` digits).

    A float ``±inf``, so that every numeric check refuses it, shown in messages by its size
    (``an integer of 5001 digits``) rather than in full.
    """

    digits: int

    def __new__(cls, text: str) -> HugeInteger:
        self = super().__new__(cls, "-inf" if text.lstrip().startswith("-") else "inf")
        self.digits = len(text.strip().lstrip("+-"))
        return self

    def __repr__(self) -> str:
        return f"an integer of {self.digits:,} digits"

    __str__ = __repr__


def _int(text: str) -> int | HugeInteger:
    return int(text) if len(text) <= MAX_INT_DIGITS else HugeInteger(text)


class _TooDeep(Exception):
    """Nesting deeper than :data:`MAX_DEPTH`, at ``path`` (where in the text, if known)."""

    def __init__(self, path: list[str | int], where: str = "") -> None:
        super().__init__(path, where)
        self.path = path
        self.where = where

    def message(self) -> str:
        shown = self.path if len(self.path) <= 8 else [*self.path[:6], "…"]
        text = ""
        for part in shown:
            if isinstance(part, int):
                text += f"[{part}]"
            elif part == "…":
                text += "…"
            else:
                text += f".{part}" if text else str(part)
        at = f" at {text}" if text else ""
        return f"nested more than {MAX_DEPTH} levels deep{at}{self.where}"


# JSON strings (escapes included), and the characters that change or count nesting
_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_JSON_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{},]')


def _json_depth(text: str) -> None:
    """Raise :class:`_TooDeep` if JSON text nests deeper than :data:`MAX_DEPTH`, before
    ``json.loads`` recurses into it."""
    # Fast: bracket depth with the strings blanked out (vectorised; a 1 MB body in ms).
    bare = _JSON_STRING.sub('""', text).encode("utf-8", "replace")
    codes = np.frombuffer(bare, dtype=np.uint8)
    step = np.isin(codes, (0x5B, 0x7B)).astype(np.int32) - np.isin(codes, (0x5D, 0x7D))
    if codes.size == 0 or int(np.cumsum(step).max()) <= MAX_DEPTH:
        return
    # Too deep: walk the tokens once more to say where (keys and indices).
    stack: list[list[Any]] = []  # [kind, key or index]
    for m in _JSON_TOKEN.finditer(text):
        tok = m.group()
        if tok in ("[", "{"):
            if len(stack) >= MAX_DEPTH:
                line = text.count("\n", 0, m.start()) + 1
                col = m.start() - text.rfind("\n", 0, m.start())
                raise _TooDeep([k for _, k in stack], f" (line {line}, column {col})")
            stack.append(["[", 0] if tok == "[" else ["{", None])
        elif tok in ("]", "}"):
            if stack:
                stack.pop()
        elif tok == ",":
            if stack and stack[-1][0] == "[":
                stack[-1][1] += 1
        elif stack and stack[-1][0] == "{":
            stack[-1][1] = tok[1:-1][:40]  # the latest key (a value string is never opened)
    raise _TooDeep([])  # unbalanced text the scan could not place; still too deep


@functools.cache
def _yaml_loader() -> type:
    """A safe YAML loader that refuses deep nesting while composing (before the composer's
    recursion) and keeps over-long integers as :class:`HugeInteger`."""
    import yaml

    class Loader(yaml.SafeLoader):
        _path: list[str | int]

        def compose_node(self, parent: Any, index: Any) -> Any:
            path = self.__dict__.setdefault("_path", [])
            if parent is not None:
                key = index.value if isinstance(index, yaml.ScalarNode) else index
                path.append(key if isinstance(key, int) else str(key)[:40])
            try:
                opens = (yaml.SequenceStartEvent, yaml.MappingStartEvent)
                if len(path) >= MAX_DEPTH and isinstance(self.peek_event(), opens):
                    mark = self.peek_event().start_mark
                    where = f" (line {mark.line + 1}, column {mark.column + 1})"
                    raise _TooDeep(path[:-1], where)
                return super().compose_node(parent, index)
            finally:
                if parent is not None:
                    path.pop()

        def construct_yaml_int(self, node: Any) -> Any:
            # Sexagesimal and long literals cost quadratic time in int(); refuse them cheaply.
            if len(node.value) > MAX_INT_DIGITS:
                return HugeInteger(node.value)
            return super().construct_yaml_int(node)

    Loader.add_constructor("tag:yaml.org,2002:int", Loader.construct_yaml_int)
    # YAML 1.1 reads 1e-3 and 2.5e3 (no dot, or no exponent sign) as text; YAML 1.2 and JSON
    # read numbers, and a number given as text is refused by validation.
    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
        list("-+0123456789."),
    )
    return Loader


def nul_paths(data: Any, path: str = "") -> list[str]:
    """The paths (``grid.name``, ``items[2]``) of keys and strings in parsed data that hold a
    NUL character: no name or value has one, and databases refuse it."""
    out: list[str] = []
    if isinstance(data, str):
        return [path or "(root)"] if "\x00" in data else []
    if isinstance(data, dict):
        for k, v in data.items():
            key = str(k)
            sub = f"{path}.{key}" if path else key
            if "\x00" in key:
                out.append(sub.replace("\x00", "\\x00"))
            else:
                out += nul_paths(v, sub)
    elif isinstance(data, list):
        for i, v in enumerate(data):
            out += nul_paths(v, f"{path}[{i}]")
    return out


def _data_depth(data: Any) -> None:
    """Raise :class:`_TooDeep` if parsed data nests deeper than :data:`MAX_DEPTH`. YAML aliases
    can nest a shallow text deeply; shared nodes are measured once, so an alias bomb costs
    no more than its text."""
    depth: dict[int, int] = {}
    todo: list[tuple[Any, bool]] = [(data, False)]
    while todo:
        node, done = todo.pop()
        if not isinstance(node, (dict, list)) or (id(node) in depth and not done):
            continue
        children = list(node.values()) if isinstance(node, dict) else node
        if done:
            depth[id(node)] = 1 + max(
                (depth.get(id(c), 0) for c in children if isinstance(c, (dict, list))),
                default=0,
            )
            if depth[id(node)] > MAX_DEPTH:
                raise _TooDeep([])
        else:
            depth[id(node)] = 0  # being measured (a recursive alias stops here)
            todo.append((node, True))
            todo.extend((c, False) for c in children)


def file_format(path: str | os.PathLike[str]) -> Format:
    """``json`` for a ``.json`` file, else ``yaml``."""
    return "json" if Path(path).suffix.lower() == ".json" else "yaml"


def parse_study_text(text: str, fmt: Format) -> Any:
    """Parse study text (YAML with ``yaml.safe_load``, or JSON) into plain data.

    Integer literals longer than :data:`MAX_INT_DIGITS` come back as :class:`HugeInteger`.

    Raises
    ------
    StudyFileError
        ``not valid YAML: ...`` or ``not valid JSON: ...``; ``nested more than 32 levels
        deep at PATH (line L, column C)``.
    """
    try:
        if fmt == "json":
            _json_depth(text)
            return json.loads(text, parse_int=_int)
        import yaml

        data = yaml.load(text, Loader=_yaml_loader())  # a SafeLoader subclass: safe
        _data_depth(data)
        return data
    except _TooDeep as exc:
        raise StudyFileError(exc.message(), exc) from None
    except RecursionError as exc:  # not expected past the depth checks; never a 500
        raise StudyFileError(f"nested too deeply to read as {fmt.upper()}", exc) from None
    except Exception as exc:  # json's ValueError, yaml.YAMLError
        raise StudyFileError(f"not valid {fmt.upper()}: {exc}", exc) from None


def read_study_file(path: str | os.PathLike[str]) -> Any:
    """Read and parse a study file (``.yaml``, ``.yml`` or ``.json``) into plain data.

    Raises
    ------
    StudyFileError
        ``cannot read study file PATH: ...`` or ``PATH: not valid YAML: ...`` (or JSON).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise StudyFileError(f"cannot read study file {p}: {exc.strerror}", exc) from None
    try:
        data = parse_study_text(text, file_format(p))
        return _with_tables(data, p.parent)
    except StudyFileError as exc:
        raise StudyFileError(f"{p}: {exc}", exc.cause) from None


#: The columns of a base amplitude table file (others are allowed and ignored).
TABLE_COLUMNS = ("frequency_hz", "base_amplitude_m")


def _with_tables(data: Any, folder: Path) -> Any:
    """``data`` with a table file named in ``physical.base_amplitude_table`` replaced by its
    rows and name (``{file, frequency_hz, base_amplitude_m}``)."""
    physical = data.get("physical") if isinstance(data, dict) else None
    name = physical.get("base_amplitude_table") if isinstance(physical, dict) else None
    if not isinstance(name, str):
        return data  # absent, or rows given inline: validation checks them
    try:
        rows = read_amplitude_table(folder / name)
    except StudyFileError as exc:
        raise StudyFileError(f"physical.base_amplitude_table: {exc}", exc.cause) from None
    return {**data, "physical": {**physical, "base_amplitude_table": {"file": name, **rows}}}


def read_amplitude_table(path: str | os.PathLike[str]) -> dict[str, list[float]]:
    """Read a base amplitude table: CSV with a header naming ``frequency_hz`` and
    ``base_amplitude_m`` (SI units; other columns ignored), one row per frequency; blank lines
    and lines starting with ``#`` (notes on where the values came from) are skipped.

    Returns
    -------
    dict
        ``{"frequency_hz": [...], "base_amplitude_m": [...]}`` in the file's row order; the
        ranges and the match with the grid are checked by the study's validation.

    Raises
    ------
    StudyFileError
        The file cannot be read, lacks a column, or has a value that is not a finite number
        (the message names the file, the line and the column).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or str(exc)
        raise StudyFileError(f"cannot read table file {p}: {why}", exc) from None
    lines = [
        (i, line)
        for i, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines:
        raise StudyFileError(f"{p}: empty table; a header {','.join(TABLE_COLUMNS)} and one "
                             "row per frequency are needed", ValueError(p))  # fmt: skip
    # One line, one row (no quoted line breaks in a table of numbers).
    rows = [next(csv.reader([line]), []) for _, line in lines]
    header = [h.strip() for h in rows[0]]
    missing = [c for c in TABLE_COLUMNS if c not in header]
    if missing:
        raise StudyFileError(
            f"{p}: line {lines[0][0]}: the header must name the columns "
            f"{', '.join(TABLE_COLUMNS)}; got {', '.join(header)}, missing {', '.join(missing)}",
            ValueError(missing),
        )
    where = {c: header.index(c) for c in TABLE_COLUMNS}
    out: dict[str, list[float]] = {c: [] for c in TABLE_COLUMNS}
    for (number, _), row in zip(lines[1:], rows[1:], strict=True):
        for c, j in where.items():
            cell = row[j].strip() if j < len(row) else ""
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise StudyFileError(
                    f"{p}: line {number}: {c} must be a finite number, got {cell!r}",
                    ValueError(cell),
                )
            out[c].append(value)
    return out
