"""Typed configuration files: a TOML or JSON table read into frozen dataclasses.

Unknown keys, missing keys and wrong types are refused naming the key (``[options].substeps:
expected an integer, got 'x'``); numbers accept integers, never booleans. Values out of
range are refused by each config's ``__post_init__`` (a DanoError naming the field). The one
reader of configuration files: ``dano sysid``, ``dano trajopt`` and ``dano simulate --config``
and the ``config`` of a saved field all come through :func:`read_table` /
:func:`typed_table`.

Every config dataclass documents its fields with attribute docstrings (a string below each
field: quantity [unit], shape); :func:`field_docs` reads them and :func:`schema_markdown`
writes a TOML schema's reference (``docs/config-reference.md``, by
``scripts/make_config_docs.py``).
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import json
import textwrap
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


#: how a number setting may be written as a string in a JSON configuration: "inf", "-inf"
#: (JSON has no infinity; :func:`dano._files.config_json` writes these, TOML has its own ``inf``)
INFINITE_WORDS = ("inf", "infinity")


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
        word = value.strip().lower() if isinstance(value, str) else ""
        if word.lstrip("+-") in INFINITE_WORDS and len(word) - len(word.lstrip("+-")) <= 1:
            return float("-inf") if word.startswith("-") else float("inf")
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




def check_ranges(config, checks):
    """``config`` if every ``(setting name, ok)`` in ``checks`` holds; raises DanoError
    naming the first setting out of range, its value and its documentation, which states
    the range (``horizon out of range: 1 (Horizon T [steps], 2 to 10,000.)``). For a
    config's ``__post_init__``."""
    for name, ok in checks:
        if not ok:
            doc = field_docs(type(config)).get(name) if dataclasses.is_dataclass(config) else None
            raise DanoError(f"{name} out of range: {getattr(config, name)}" + (f" ({doc})" if doc else ""))
    return config


# ------------------------------------------------------------------ field documentation
# A config dataclass documents each field with a string right below it (an attribute
# docstring, as tyro and nerfstudio read them): the CLI's help and docs/config-reference.md.


@functools.lru_cache(maxsize=None)
def _own_field_docs(cls) -> dict:
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    node = next((n for n in ast.parse(source).body if isinstance(n, ast.ClassDef)), None)
    docs, body = {}, node.body if node is not None else []
    for stmt, after in zip(body, body[1:]):
        if (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
            docs[stmt.target.id] = " ".join(inspect.cleandoc(after.value.value).split())
    return docs


def field_docs(cls) -> dict[str, str]:
    """{field name: its attribute docstring, on one line} of the dataclass ``cls`` (fields
    inherited from dataclass bases included, a redeclared field's own docstring first);
    fields without one are left out."""
    docs = {}
    for klass in reversed(cls.__mro__):
        if dataclasses.is_dataclass(klass):
            docs.update(_own_field_docs(klass))
    return {f.name: docs[f.name] for f in dataclasses.fields(cls) if f.name in docs}


def _table_class(tp):
    """(dataclass, is an array of tables) for a table-valued type, else (None, False)."""
    if dataclasses.is_dataclass(tp):
        return tp, False
    args = typing.get_args(tp)
    if typing.get_origin(tp) is tuple and len(args) == 2 and args[1] is Ellipsis and dataclasses.is_dataclass(args[0]):
        return args[0], True
    return None, False


def _type_name(tp) -> str:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        rest = [a for a in args if a is not type(None)]
        return " or ".join(_type_name(a) for a in rest) + (" (optional)" if type(None) in args else "")
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return "array of tables" if dataclasses.is_dataclass(args[0]) else f"array of {_type_name(args[0])}s"
        return f"array of {len(args)} {_type_name(args[0])}s" if len(set(args)) == 1 else "array"
    if origin is dict:
        return f"table of {_type_name(args[1])}s"
    if dataclasses.is_dataclass(tp):
        return "table"
    return {bool: "boolean", int: "integer", float: "number", str: "string", Path: "string"}.get(tp, str(tp))


def _toml_value(value) -> str:
    if value is None:
        return "left out"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, float):
        return repr(value)
    return json.dumps(value) if isinstance(value, str) else str(value)


def _default(f: dataclasses.Field, tp) -> str:
    if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
        return "required"
    value = f.default if f.default is not dataclasses.MISSING else f.default_factory()
    if dataclasses.is_dataclass(value):
        return "see below"
    return "`" + _toml_value(value) + "`" if value is not None else "left out"


def schema_markdown(cls, title: str, level: int = 2, intro: str = "") -> str:
    """Markdown reference of the configuration dataclass ``cls`` as a TOML file: a heading
    ``title`` and, per table (the top level, nested tables ``[name]`` and arrays of tables
    ``[[name]]``, recursively), a table of key, type, default and description (the
    field's docstring, :func:`field_docs`). Raises DanoError naming a field without a
    docstring."""
    parts = [f"{'#' * level} {title}\n"]
    if intro:
        parts.append(intro.strip() + "\n")

    def table(klass, name: str | None, array: bool):
        docs = field_docs(klass)
        hints = typing.get_type_hints(klass)
        head = "Top level" if name is None else f"`[[{name}]]`" if array else f"`[{name}]`"
        rows, nested = [], []
        for f in dataclasses.fields(klass):
            if f.name not in docs:
                raise DanoError(f"{klass.__name__}.{f.name}: no docstring (write one below the field)")
            sub, sub_array = _table_class(hints[f.name])
            key = f.name if name is None else f"{name}.{f.name}"
            if sub is not None:
                nested.append((sub, key, sub_array))
                ref = f"`[[{key}]]`" if sub_array else f"`[{key}]`"
                rows.append((f.name, f"{_type_name(hints[f.name])} ({ref})", _default(f, hints[f.name]), docs[f.name]))
            else:
                rows.append((f.name, _type_name(hints[f.name]), _default(f, hints[f.name]), docs[f.name]))
        cells = lambda r: "| " + " | ".join(c.replace("|", "\\|") for c in r) + " |"
        parts.append(f"{'#' * (level + 1)} {head}\n\n" + "\n".join(
            [cells(("key", "type", "default", "description")), "|---|---|---|---|"] + [cells(r) for r in rows]) + "\n")
        for sub, key, sub_array in nested:
            table(sub, key, sub_array)

    table(cls, None, False)
    return "\n".join(parts)
