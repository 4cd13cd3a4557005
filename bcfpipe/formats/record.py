"""Frozen dataclasses as JSON records: one generic ``to_json``/``from_json`` for bcfpipe's files.

A record's fields are its JSON keys, in order. Field types drive the reading: ``int``, ``float``
(an int is accepted), ``str``, ``bool``, ``X | None``, ``tuple[X, ...]``, ``list[X]``,
``dict[str, X]``, ``Any``, enums (by value) and nested records. A field whose metadata has ``omit_none`` is left
out of the JSON when it is None (keys that only some writers add); ``_ORDER`` (a class attribute)
lists keys that lead the object. Unknown keys are refused, so a
file that does not match the contract fails where it is read, naming the key.
"""
from __future__ import annotations

import dataclasses
from enum import Enum
import json
import types
import typing
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, TypeVar

from bcfpipe.errors import InputError

R = TypeVar("R", bound="Record")
OMIT_NONE = {"omit_none": True}


class FormatError(InputError):
    """A file does not follow its bcfpipe contract (exit code 2)."""


def optional(default=None):
    """A field that is left out of the JSON while it is None."""
    return dataclasses.field(default=default, metadata=OMIT_NONE)


@lru_cache(maxsize=None)
def field_hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


class Record:
    """Mixin for frozen dataclasses that are JSON objects."""

    def to_json(self) -> dict[str, Any]:
        return _fields_json(self)

    @classmethod
    def from_json(cls: type[R], data: Any, where: str = "") -> R:
        return _load(cls, data, where or cls.__name__)

    def dumps(self) -> str:
        """The file's text: two-space indent, keys in field order, a final newline."""
        return json.dumps(self.to_json(), indent=2) + "\n"


def key_order(cls) -> list[str]:
    """JSON key order: the record's ``_ORDER`` first (keys that must lead but have defaults), then
    its fields in declaration order."""
    names = [f.name for f in dataclasses.fields(cls)]
    first = list(getattr(cls, "_ORDER", ()))
    return first + [n for n in names if n not in first]


def _fields_json(v: Any) -> dict[str, Any]:
    omit = {f.name for f in dataclasses.fields(v) if f.metadata.get("omit_none") and getattr(v, f.name) is None}
    return {name: _dump(getattr(v, name)) for name in key_order(type(v)) if name not in omit}


def _dump(v: Any) -> Any:
    if isinstance(v, Enum):  # a named value (formats.vocabulary): its string
        return v.value
    if isinstance(v, Record):
        return v.to_json()
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return _fields_json(v)
    if isinstance(v, (list, tuple)):
        return [_dump(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _dump(x) for k, x in v.items()}
    return v


def _fail(where: str, what: str) -> FormatError:
    return FormatError(f"{where}: {what}")


def _load(tp: Any, v: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return v
    if isinstance(tp, type) and issubclass(tp, Enum):  # a named value (formats.vocabulary), by its string
        try:
            return tp(v)
        except ValueError:
            raise _fail(where, f"unknown value {v!r}; choose from {', '.join(str(m.value) for m in tp)}") from None
    if origin in (typing.Union, types.UnionType):
        if v is None and type(None) in args:
            return None
        rest = [a for a in args if a is not type(None)]
        errors = []
        for a in rest:
            try:
                return _load(a, v, where)
            except FormatError as e:
                errors.append(str(e))
        raise FormatError(errors[0]) if errors else _fail(where, "unexpected value")
    if dataclasses.is_dataclass(tp):
        if not isinstance(v, dict):
            raise _fail(where, f"expected an object, got {type(v).__name__}")
        fields = {f.name: f for f in dataclasses.fields(tp)}
        unknown = sorted(set(v) - set(fields))
        if unknown:
            raise _fail(where, f"unknown key {unknown[0]!r}")
        hints = field_hints(tp)
        kw = {}
        for name, f in fields.items():
            if name in v:
                kw[name] = _load(hints[name], v[name], f"{where}.{name}")
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise _fail(where, f"missing key {name!r}")
        return tp(**kw)
    if origin in (tuple, list):
        if not isinstance(v, (list, tuple)):  # JSON gives lists; asdict() of a record, tuples
            raise _fail(where, f"expected a list, got {type(v).__name__}")
        item = args[0] if args else Any
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            if len(args) != len(v):
                raise _fail(where, f"expected {len(args)} items, got {len(v)}")
            return tuple(_load(a, x, f"{where}[{i}]") for i, (a, x) in enumerate(zip(args, v)))
        out = [_load(item, x, f"{where}[{i}]") for i, x in enumerate(v)]
        return tuple(out) if origin is tuple else out
    if origin is dict:
        if not isinstance(v, dict):
            raise _fail(where, f"expected an object, got {type(v).__name__}")
        return {k: _load(args[1], x, f"{where}.{k}") for k, x in v.items()}
    if tp is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise _fail(where, f"expected a number, got {type(v).__name__}")
        return float(v)
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise _fail(where, f"expected an integer, got {type(v).__name__}")
        return v
    if tp in (str, bool):
        if not isinstance(v, tp):
            raise _fail(where, f"expected {'a string' if tp is str else 'true or false'}, got {type(v).__name__}")
        return v
    raise TypeError(f"{where}: unsupported field type {tp!r}")


def read(cls: type[R], path, fmt: str | None = None, version: int | None = None,
         compatible: tuple[int, ...] = (), upgrade: Callable[[dict], dict] | None = None) -> R:
    """Parse ``path`` as a ``cls`` record; a ``format``/``format_version`` mismatch is refused.
    ``compatible``: older versions also read, after ``upgrade`` (which gets the parsed JSON of an
    older version and returns it in this version's keys)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as e:
        raise FormatError(f"{path}: {e.strerror or e}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FormatError(f"{path}: not JSON ({e})") from None
    if fmt is not None:
        if not isinstance(data, dict) or data.get("format") != fmt:
            raise FormatError(f"{path}: not a {fmt} file")
        if data.get("format_version") not in (version, *compatible):
            raise FormatError(f"{path}: {fmt} version {data.get('format_version')}; this bcfpipe reads "
                              f"version {version}")
    if upgrade is not None and fmt is not None and data.get("format_version") != version:
        data = upgrade(data)
    return cls.from_json(data, path.name)
