"""Typed configuration files: a TOML or JSON table read into frozen dataclasses.

Unknown keys, missing keys and wrong types are refused naming the key (``[options].substeps:
expected an integer, got 'x'``); numbers accept integers, never booleans. Used by ``dano
sysid`` and ``dano simulate --config``.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
import types
import typing
from pathlib import Path

from .errors import DanoError, FileFormatError


def read_table(path: str | Path) -> dict:
    """The top-level table of a TOML (or, by suffix, JSON) file. Raises FileFormatError."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise FileFormatError(f"{path}: no such configuration file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FileFormatError(f"{path}: cannot read ({exc})") from exc
    try:
        raw = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(f"{path}: not valid {'JSON' if path.suffix.lower() == '.json' else 'TOML'} "
                              f"({exc})") from exc
    if not isinstance(raw, dict):
        raise FileFormatError(f"{path}: expected a table of settings, got {_kind(raw)}")
    return raw


def typed(value, tp, where: str):
    """``value`` read as type ``tp`` (float accepts integers; never booleans)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None:
            return None
        return typed(value, next(a for a in args if a is not type(None)), where)
    if origin is tuple:
        if not isinstance(value, list):
            raise DanoError(f"{where}: expected an array, got {_kind(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(typed(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise DanoError(f"{where}: expected {len(args)} values, got {len(value)}")
        return tuple(typed(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if dataclasses.is_dataclass(tp):
        return typed_table(value, tp, where)
    if origin is dict:
        if not isinstance(value, dict):
            raise DanoError(f"{where}: expected a table, got {_kind(value)}")
        return {k: typed(v, args[1], f"{where}.{k}") for k, v in value.items()}
    if tp is bool:
        if not isinstance(value, bool):
            raise DanoError(f"{where}: expected true or false, got {_kind(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise DanoError(f"{where}: expected a number, got {_kind(value)}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise DanoError(f"{where}: expected an integer, got {_kind(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise DanoError(f"{where}: expected a string, got {_kind(value)}")
        return value
    raise TypeError(f"unsupported schema type {tp}")  # a bug in the schema, not in the file


def _kind(value) -> str:
    return {dict: "a table", list: "an array", str: f"the string {value!r}", bool: f"{value!r}".lower()}.get(
        type(value), repr(value))


def typed_table(value, cls, where: str):
    """The dataclass ``cls`` read from the table ``value`` (a dict) found at ``where`` ("" for
    the top level); raises DanoError naming the key for unknown keys, missing required keys
    and wrong types."""
    if not isinstance(value, dict):
        raise DanoError(f"{where or 'the file'}: expected a table, got {_kind(value)}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(value) - names)
    if unknown:
        raise DanoError(f"{where or 'top level'}: unknown key {unknown[0]!r} (known: {', '.join(sorted(names))})")
    kwargs = {}
    for f in dataclasses.fields(cls):
        key = f"{where}.{f.name}" if where else f"[{f.name}]"
        if f.name in value:
            kwargs[f.name] = typed(value[f.name], hints[f.name], key)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise DanoError(f"{key}: missing")
    return cls(**kwargs)


