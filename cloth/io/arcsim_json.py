"""JSON as ARCSim's configs write it, and the typed, path-naming checks the ARCSim reader is built on.

ARCSim reads its configs with jsoncpp, which accepts ``//`` line comments and ``/* */`` block
comments wherever whitespace may stand. :func:`read_json_with_comments` blanks the comments out
(each comment character becomes a space, newlines are kept, so line and column numbers of what
remains are those of the file; comment markers inside strings are left alone) and hands the rest
to :mod:`json`. Two things jsoncpp would pass silently are errors here: a key written twice in
one object (jsoncpp keeps the last) and the non-JSON constants ``NaN``/``Infinity``.

Every value is checked where it is read, by a function that knows its key as a JSON path
(``cloths[0].materials[0].thicken``) and names it, with the config file, in the
:class:`ArcsimConfigError` it raises. As in jsoncpp, an explicit ``null`` reads as an absent key.

Used by :mod:`cloth.io.arcsim` (the config), :mod:`cloth.io.arcsim_motion` and
:mod:`cloth.io.arcsim_mesh`.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cloth.core.jsonc import strip_json_comments


class ArcsimConfigError(ValueError):
    """A config (or a file it refers to) this reader cannot turn into plain data.

    key:  the JSON path of the offending value (``cloths[0].materials[0].thicken``), or None
          for an error not tied to one key (a JSON syntax error, a .mot file read on its own);
    path: the file the error is about (the config, or a .mot file read on its own).
    The message names both.
    """

    def __init__(self, message: str, key: str | None = None, path: Path | str | None = None):
        super().__init__(message)
        self.key = key
        self.path = Path(path) if path is not None else None


# ---- JSON with comments (cloth.core.jsonc.strip_json_comments) ------------------------------------

class _DuplicateKey(Exception):
    def __init__(self, name: str):
        self.name = name


def _no_duplicates(pairs):
    obj = {}
    for name, value in pairs:
        if name in obj:
            raise _DuplicateKey(name)
        obj[name] = value
    return obj


def _reject_constant(name: str):
    raise ValueError(f"{name} is not JSON")


def read_json_with_comments(path: Path):
    """The JSON value in the file at `path`, comments allowed (see the module docstring).
    ArcsimConfigError naming the file, and the line and column of a syntax error."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ArcsimConfigError(f"{path}: cannot be read ({exc})", path=path) from None
    try:
        stripped = strip_json_comments(text)
        return json.loads(stripped, object_pairs_hook=_no_duplicates, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise ArcsimConfigError(f"{path}: line {exc.lineno} column {exc.colno}: invalid JSON: {exc.msg}",
                                path=path) from None
    except _DuplicateKey as exc:
        raise ArcsimConfigError(f"{path}: key {exc.name!r} appears twice in one object", key=exc.name,
                                path=path) from None
    except ValueError as exc:
        raise ArcsimConfigError(f"{path}: invalid JSON: {exc}", path=path) from None


# ---- typed, path-naming access --------------------------------------------------------------------

def join_key(parent: str, name: str | int) -> str:
    """The JSON path of member `name` (a key, or an index) of the value at `parent`."""
    if isinstance(name, int):
        return f"{parent}[{name}]"
    return f"{parent}.{name}" if parent else name


@dataclass(frozen=True)
class ConfContext:
    """Where a config is read from: its file (named in every error) and the directory its
    relative file names are resolved against (ARCSim's working directory)."""

    conf_path: Path  # absolute
    root: Path  # absolute

    def error(self, key: str | None, message: str) -> ArcsimConfigError:
        where = f"{self.conf_path}: {key}" if key else f"{self.conf_path}"
        return ArcsimConfigError(f"{where}: {message}", key=key, path=self.conf_path)

    def existing_file(self, name: str, key: str) -> Path:
        """The absolute path of file `name` (relative names against the root); an error naming
        the key, the path and the config file if there is no such file."""
        path = Path(os.path.abspath(self.root / Path(name).expanduser()))
        if not path.is_file():
            raise self.error(key, f"no such file: {path} (relative names are resolved against {self.root})")
        return path


def as_object(value, key: str, ctx: ConfContext) -> dict:
    if not isinstance(value, dict):
        raise ctx.error(key, f"expected an object, found {_show(value)}")
    return value


def as_list(value, key: str, ctx: ConfContext) -> list:
    if not isinstance(value, list):
        raise ctx.error(key, f"expected an array, found {_show(value)}")
    return value


def as_number(value, key: str, ctx: ConfContext) -> float:
    """A JSON number (integer or real; not a boolean) as a float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ctx.error(key, f"expected a number, found {_show(value)}")
    x = float(value)
    if not math.isfinite(x):
        raise ctx.error(key, f"expected a finite number, found {_show(value)}")
    return x


def as_int(value, key: str, ctx: ConfContext) -> int:
    """A JSON integer (jsoncpp's isIntegral: not a real, not a boolean)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ctx.error(key, f"expected an integer, found {_show(value)}")
    return value


def as_bool(value, key: str, ctx: ConfContext) -> bool:
    if not isinstance(value, bool):
        raise ctx.error(key, f"expected true or false, found {_show(value)}")
    return value


def as_string(value, key: str, ctx: ConfContext) -> str:
    if not isinstance(value, str):
        raise ctx.error(key, f"expected a string, found {_show(value)}")
    return value


def as_vector(value, key: str, ctx: ConfContext, n: int) -> np.ndarray:
    """(n,) float64 from an array of exactly n numbers."""
    items = as_list(value, key, ctx)
    if len(items) != n:
        raise ctx.error(key, f"expected an array of {n} numbers, found {len(items)} element(s): {_show(value)}")
    return np.array([as_number(v, join_key(key, i), ctx) for i, v in enumerate(items)], dtype=np.float64)


def member(obj: dict, name: str, parent: str, ctx: ConfContext, convert, default=None, required: bool = False):
    """convert(obj[name], its key, ctx), or `default` when the key is absent or null (as jsoncpp
    reads it); an error naming the key when it is required and absent."""
    key = join_key(parent, name)
    value = obj.get(name)
    if value is None:
        if required:
            raise ctx.error(key, "is required")
        return default
    return convert(value, key, ctx)


def check_keys(obj: dict, parent: str, ctx: ConfContext, supported: Iterable[str],
               unsupported: Mapping[str, str] | None = None, renamed: Mapping[str, str] | None = None) -> None:
    """Every key of `obj` is `supported`; a key ARCSim knows but this reader does not support
    (`unsupported`: key -> what it is), a key ARCSim spells otherwise (`renamed`: key -> ARCSim's
    key) and any other key each raise an error naming the key."""
    supported = tuple(supported)
    unsupported, renamed = unsupported or {}, renamed or {}
    for name in obj:
        if name in supported:
            continue
        key = join_key(parent, name)
        if name in unsupported:
            raise ctx.error(key, f"not supported by this reader: {unsupported[name]}")
        if name in renamed:
            raise ctx.error(key, f"unknown key: ARCSim reads this as {renamed[name]!r}")
        raise ctx.error(key, f"unknown key (known here: {', '.join(supported)})")


def _show(value) -> str:
    """A short rendering of a JSON value for a message."""
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."
