"""Command-line options derived from a dataclass: one ``--flag`` per field, its help from the field's docstring.

A settings dataclass is the single list of options (CleanRL's ``Args`` read by tyro, without the dependency):

    @dataclass
    class Config:
        seed: int = 0
        'training seed'       # the string literal under a field (triple-quoted in train/config.py)

gives ``--seed SEED  training seed (default: 0)``. The field's type decides the form: ``int``/``float``/``str``
(optionally ``| None``) take a value; ``bool`` is a switch (``--resume`` for a False default, ``--no-progress``
for a True one); ``dict`` is ``--hp KEY=JSON``, repeatable. Every option defaults to None in the parser, so
"not given" stays visible (``--seed`` next to ``--seeds``); :func:`from_namespace` fills in the field defaults.
Values are converted here, not by argparse, so a bad value raises :class:`~ehss_gym.train.runs.RunError` naming
the flag (the commands print it and exit with 2) instead of exiting from inside argparse.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import json
import textwrap
import typing
from types import NoneType, UnionType

from .runs import RunError


def flag(name: str) -> str:
    """``--name-with-dashes`` of a field name."""
    return "--" + name.replace("_", "-")


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """The attribute docstrings of a dataclass (the string literal under each field), by field name."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    docs = {}
    for node, doc in zip(body, body[1:]):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(doc, ast.Expr) \
                and isinstance(doc.value, ast.Constant) and isinstance(doc.value.value, str):
            docs[node.target.id] = " ".join(doc.value.value.split())
    return docs


@functools.cache
def field_types(cls: type) -> dict[str, type]:
    """Field name -> its base type (``int | None`` -> ``int``) for the fields of a dataclass."""
    hints = typing.get_type_hints(cls)
    out = {}
    for f in dataclasses.fields(cls):
        t = hints[f.name]
        if isinstance(t, UnionType) or typing.get_origin(t) is typing.Union:
            args = [a for a in typing.get_args(t) if a is not NoneType]
            if len(args) != 1:
                raise TypeError(f"{cls.__name__}.{f.name}: only 'X | None' unions are supported, got {t}")
            t = args[0]
        if t not in (bool, int, float, str, dict):
            raise TypeError(f"{cls.__name__}.{f.name}: type {t} has no command-line form")
        out[f.name] = t
    return out


def _default(f: dataclasses.Field):
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


def add_options(parser: argparse.ArgumentParser, cls: type, exclude=(), choices=None,
                metavars=None) -> argparse.ArgumentParser:
    """Add one option per field of dataclass ``cls`` (the module docstring gives the forms) to ``parser``;
    ``choices`` maps a field to the values it accepts (shown in the help, checked by argparse), ``metavars`` to the
    values shown in the help only (checked where the value is used)."""
    docs, types = field_docs(cls), field_types(cls)
    choices = choices or {}
    metavars = metavars or {}
    for f in dataclasses.fields(cls):
        if f.name in exclude:
            continue
        t, default, doc = types[f.name], _default(f), docs.get(f.name, "")
        if t is bool:
            opt = flag(f.name) if not default else "--no-" + f.name.replace("_", "-")
            parser.add_argument(opt, dest=f.name, action="store_const", const=not default, default=None,
                                help=doc if not default else f"turn off {doc} (on by default)")
        elif t is dict:
            parser.add_argument(flag(f.name), dest=f.name, action="append", default=None, metavar="KEY=JSON",
                                help=f"{doc}; repeatable")
        else:
            shown = "" if default is None else f" (default: {default})"
            opts = {"choices": tuple(choices[f.name])} if f.name in choices else {
                "metavar": "{" + ",".join(metavars[f.name]) + "}" if f.name in metavars else f.name.upper()}
            parser.add_argument(flag(f.name), dest=f.name, default=None, help=doc + shown, **opts)
    return parser


def parse_pairs(name: str, items) -> dict:
    """``KEY=JSON`` strings -> dict; RunError naming the option on a malformed item."""
    out = {}
    for item in items or []:
        key, sep, val = item.partition("=")
        if not sep or not key.strip():
            raise RunError(f"{flag(name)} must be KEY=JSON (e.g. gamma=0.99), got {item!r}")
        try:
            out[key.strip()] = json.loads(val)
        except ValueError:
            raise RunError(f"{flag(name)} {key.strip()}: value {val!r} is not JSON (strings need quotes)") from None
    return out


def convert(name: str, t: type, raw):
    """The command-line text ``raw`` of field ``name`` as type ``t``; RunError naming the option."""
    if t is dict:
        return parse_pairs(name, raw)
    if t in (bool, str):
        return raw
    try:
        return t(raw)
    except (TypeError, ValueError):
        kind = "an integer" if t is int else "a number"
        raise RunError(f"{flag(name)} must be {kind}, got {raw!r}") from None


def from_namespace(cls: type, ns: argparse.Namespace, **overrides):
    """An instance of dataclass ``cls`` from parsed options: given values converted, the others at their defaults.

    Args:
        cls: the dataclass whose options :func:`add_options` added.
        ns: the parsed namespace.
        **overrides: field values that replace what was parsed (already typed).
    """
    types = field_types(cls)
    values = {}
    for f in dataclasses.fields(cls):
        raw = getattr(ns, f.name, None)
        if f.name in overrides:
            values[f.name] = overrides[f.name]
        elif raw is not None:
            values[f.name] = convert(f.name, types[f.name], raw)
    return cls(**values)


def to_argv(obj, exclude=()) -> list[str]:
    """The options that rebuild dataclass instance ``obj`` through :func:`from_namespace`: every value given (so a
    command line shows all settings), switches only where they differ from the default, None values left out."""
    argv = []
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        t = field_types(type(obj))[f.name]
        if f.name in exclude or value is None or (t is bool and value == _default(f)):
            continue
        if t is bool:
            argv.append(flag(f.name) if value else "--no-" + f.name.replace("_", "-"))
        elif t is dict:
            for key, v in value.items():
                argv += [flag(f.name), f"{key}={json.dumps(v)}"]
        else:
            argv += [flag(f.name), str(value)]
    return argv


__all__ = ["flag", "field_docs", "field_types", "add_options", "parse_pairs", "convert", "from_namespace", "to_argv"]
