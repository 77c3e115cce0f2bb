"""Command-line flags derived from a frozen config dataclass: each setting is defined once, as a field;
and field values read from plain data (YAML, ``--set``) by the same types.

A field's flag comes from its type (``Literal`` -> choices, ``bool`` -> a switch, ``tuple[float, float]`` ->
two values, ``X | None`` -> optional), its default and its docstring (the help text, markup removed);
its metadata may name the flag (``{"flag": "--views"}``; ``None``: no flag), a ``metavar``, a ``group``
of the help page and ``nargs`` for variable-length tuples. A field whose type is itself such a
dataclass (``{"nested": True}``) contributes that dataclass's flags. Error messages name a setting by
:func:`flag_name`, so they always say the flag the parser has.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import re
import textwrap
import types
import typing
from typing import Any, Literal

from mvsformerpp.errors import InputError


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of the dataclass ``cls`` (from its source), by field name."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):  # no source at hand: fields without help
        return {}
    body = tree.body[0].body
    docs: dict[str, str] = {}
    for stmt, nxt in zip(body, body[1:]):
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and isinstance(nxt, ast.Expr) \
                and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str):
            docs[stmt.target.id] = inspect.cleandoc(nxt.value.value)
    return docs


def plain_text(doc: str) -> str:
    """A docstring as one paragraph of plain text: the first paragraph, reST roles and literals unwrapped."""
    first = doc.split("\n\n")[0]
    text = re.sub(r":\w+:`~?([^`]+)`", lambda m: m.group(1).split(".")[-1] if m.group(1)[:1] == "." else m.group(1),
                  first)
    text = re.sub(r"``([^`]+)``", r"\1", text)
    return " ".join(text.split())


def _fields(cls: type) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls)}


def flag_name(cls: type, name: str) -> str:
    """The command-line flag of field ``name`` of ``cls``: its ``flag`` metadata, else ``--name-like-this``
    (a field without a flag is named as a field of ``cls``)."""
    meta = _fields(cls)[name].metadata
    if "flag" in meta:
        return meta["flag"] or f"{name} (a {cls.__name__} field)"
    return "--" + name.replace("_", "-")


def _flag_fields(cls: type, names: typing.Iterable[str] | None) -> list[tuple[type, dataclasses.Field]]:
    """(owner class, field) of every field with a flag, nested dataclasses expanded in place."""
    out = []
    for name, f in _fields(cls).items():
        if names is not None and name not in names:
            continue
        if f.metadata.get("nested"):
            out.extend(_flag_fields(typing.get_type_hints(cls)[name], None))
        elif f.metadata.get("flag", "") is not None:
            out.append((cls, f))
    return out


def _unwrap_optional(tp: Any) -> Any:
    args = typing.get_args(tp)
    if (typing.get_origin(tp) in (typing.Union, types.UnionType)) and type(None) in args:
        rest = [a for a in args if a is not type(None)]
        return rest[0] if len(rest) == 1 else tp
    return tp


def _argument(cls: type, f: dataclasses.Field) -> tuple[str, dict[str, Any]]:
    """The flag of field ``f`` and its ``add_argument`` keywords."""
    tp = _unwrap_optional(typing.get_type_hints(cls)[f.name])
    default = f.default
    kw: dict[str, Any] = {"dest": f.name, "default": default}
    if "metavar" in f.metadata:
        kw["metavar"] = f.metadata["metavar"]
    shown = default
    if tp is bool:
        kw["action"] = "store_true"
        shown = None
    elif typing.get_origin(tp) is Literal:
        kw["choices"] = typing.get_args(tp)
    elif typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        kw["type"] = args[0]
        kw["nargs"] = f.metadata.get("nargs", len(args) if args[-1] is not Ellipsis else "+")
        shown = " ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in default) if default else None
    elif tp in (int, float, str):
        kw["type"] = tp
    else:
        raise TypeError(f"{cls.__name__}.{f.name}: no command-line form for type {tp!r}")
    help_text = plain_text(field_docs(cls).get(f.name, ""))
    if shown is not None and shown != "":
        help_text += f" (default: {shown})"
    kw["help"] = help_text.replace("%", "%%")
    return flag_name(cls, f.name), kw


def add_config_flags(parser: argparse.ArgumentParser, cls: type, names: typing.Iterable[str] | None = None,
                     groups: dict[str, argparse._ArgumentGroup] | None = None,
                     default_notes: dict[str, str] | None = None, **defaults: Any) -> None:
    """Add the flags of ``cls``'s fields (all, or those in ``names``) to ``parser``; a field's ``group``
    metadata puts it into ``groups[group]`` (created on ``parser`` when missing). ``defaults`` override
    field defaults by name (another command's default for the same setting); ``default_notes`` say in
    words what a default means there (e.g. "the preset's")."""
    groups = {} if groups is None else groups
    names = None if names is None else set(names)
    default_notes = default_notes or {}
    for owner, f in _flag_fields(cls, names):
        flag, kw = _argument(owner, f)
        if f.name in defaults or f.name in default_notes:
            kw["default"] = defaults.get(f.name, kw["default"])
            shown = default_notes.get(f.name, kw["default"])
            kw["help"] = re.sub(r" \(default: [^)]*\)$", "", kw["help"])
            if shown is not None:
                kw["help"] += f" (default: {shown})"
        title = f.metadata.get("group")
        target = parser
        if title is not None:
            target = groups.get(title) or groups.setdefault(title, parser.add_argument_group(title))
        target.add_argument(flag, **kw)


def config_from_args(cls: type, args: argparse.Namespace, **fixed: Any):
    """An instance of ``cls`` from the parsed flags of :func:`add_config_flags` (fields without a parsed
    flag keep their defaults; ``fixed`` sets fields by name)."""
    values: dict[str, Any] = {}
    hints = typing.get_type_hints(cls)
    for name, f in _fields(cls).items():
        if name in fixed:
            values[name] = fixed[name]
        elif f.metadata.get("nested"):
            values[name] = config_from_args(hints[name], args)
        elif hasattr(args, name):
            value = getattr(args, name)
            values[name] = tuple(value) if isinstance(value, list) else value
    return cls(**values)


def plain_value(value: Any, hint: Any, what: str) -> Any:
    """``value`` read from plain data (YAML, JSON, ``--set``) as a field of type ``hint``: tuples from lists,
    floats from ints; an :class:`~mvsformerpp.errors.InputError` naming ``what`` (e.g. "training config
    field 'lr'") when it is not one."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if value is None:
        if type(None) in args:
            return None
        raise InputError(f"{what} cannot be null")
    if origin in (typing.Union, types.UnionType):
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return plain_value(value, a, what)
            except InputError as e:
                errors.append(str(e))
        raise InputError(errors[0])
    if origin is Literal:
        if value not in args:
            raise InputError(f"{what} must be one of {list(args)}, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise InputError(f"{what} needs a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(plain_value(v, args[0], what) for v in value)
        if len(value) != len(args):
            raise InputError(f"{what} needs {len(args)} values, got {value!r}")
        return tuple(plain_value(v, a, what) for v, a in zip(value, args))
    if hint is float and isinstance(value, str):  # YAML 1.1 reads 1e-4 (no dot) as a string
        try:
            return float(value)
        except ValueError:
            pass
    plain = _PLAIN.get(dict if origin is dict else hint)
    if plain is None:
        return value
    words, accepts, convert = plain
    if not accepts(value):
        raise InputError(f"{what} needs {words}, got {value!r}")
    return convert(value)


_PLAIN = {
    dict: ("a mapping", lambda v: isinstance(v, dict), dict),
    bool: ("true/false", lambda v: isinstance(v, bool), bool),
    int: ("an integer", lambda v: isinstance(v, int) and not isinstance(v, bool), int),
    float: ("a number", lambda v: isinstance(v, (int, float)) and not isinstance(v, bool), float),
    str: ("a string", lambda v: isinstance(v, str), str),
}
"""Plain field types: (what a value must be, in words; the test; the conversion)."""
