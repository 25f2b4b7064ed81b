"""Command-line options from config dataclasses: one ``--option`` per leaf field, its help from the field's docstring.

A field's help is its attribute docstring (:func:`vision_rl.config.field_docs`), or the word of the config that holds
it; a held config's fields appear flat (:func:`vision_rl.config.flat_fields`). Bools become ``--x/--no-x``; a config
may name extra switches that set a bool to False in ``negative_switches`` (``{"disrupt_ai": "--no-disrupt"}``).
Field types: int, float, str, bool, ``tuple[int, int]`` (two values after the option, e.g. ``--image-hw-px 140
236``) and ``tuple[int, ...]`` / ``tuple[str, ...]`` (one or more).
"""

from __future__ import annotations

import argparse
import inspect
import re
from typing import Any

from vision_rl.config import field_docs, flat_fields, from_flat  # noqa: F401  (field_docs: read by the tests here)

_SCALARS = {"int": int, "float": float, "str": str}
_TUPLES = {
    "tuple[int, int]": (int, 2),
    "tuple[float, float]": (float, 2),
    "tuple[int, ...]": (int, "+"),
    "tuple[str, ...]": (str, "+"),
}


def _type_name(annotation: Any) -> str:
    """``"int"``, ``"tuple[int, int]"``... from a string annotation or a type, ``| None`` dropped."""
    name = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", None) or str(annotation)
    return " ".join(name.replace("typing.", "").replace(" | None", "").split())


def add_config_arguments(parser: argparse.ArgumentParser, config_cls: type) -> None:
    """One ``--option`` per leaf field of ``config_cls`` and of the configs it holds (:func:`flat_fields`)."""
    leaves = flat_fields(config_cls)
    flags = {flat.path[-1]: flat.name for flat in leaves} | {flat.name: flat.name for flat in leaves}
    negatives = dict(getattr(config_cls, "negative_switches", {}))

    def as_option(match: re.Match) -> str:  # ``laps`` in a docstring reads --laps on the command line
        word = match.group(1)
        return "--" + flags[word].replace("_", "-") if word in flags else word

    for flat in leaves:
        flag = "--" + flat.name.replace("_", "-")
        help_text = re.sub(r"``(\w+)``", as_option, flat.doc).rstrip(".")
        default, kind = flat.default, _type_name(flat.field.type)
        if kind == "bool":
            parser.add_argument(
                flag, dest=flat.name, action=argparse.BooleanOptionalAction, default=default, help=help_text
            )
            negative = negatives.get(flat.name) or flat.field.metadata.get("negative")
            if negative:
                parser.add_argument(negative, dest=flat.name, action="store_false", help=f"same as --no-{flag[2:]}")
        elif kind in _SCALARS:
            parser.add_argument(
                flag, dest=flat.name, type=_SCALARS[kind], default=default, help=f"{help_text} (default: {default})"
            )
        elif kind in _TUPLES:
            item, n = _TUPLES[kind]
            shown = " ".join(map(str, default)) if default is not None else None
            metavar = ("HEIGHT", "WIDTH") if flat.name.endswith("hw_px") else None
            parser.add_argument(
                flag,
                dest=flat.name,
                type=item,
                nargs=n,
                metavar=metavar,
                default=default,
                help=f"{help_text} (default: {shown})",
            )
        else:
            raise TypeError(f"{config_cls.__name__}.{flat.name}: options must be int, float, str, bool or a tuple")


def config_from_args(config_cls: type, args: argparse.Namespace) -> Any:
    """The config built from parsed options (lists of ``nargs`` options become tuples)."""
    values = {flat.name: getattr(args, flat.name) for flat in flat_fields(config_cls)}
    return from_flat(config_cls, {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def parse_config(config_cls: type, argv: list[str], prog: str | None = None) -> Any:
    """Parse ``argv`` into a ``config_cls``; the parser's description is the class docstring."""
    parser = argparse.ArgumentParser(prog=prog, description=inspect.getdoc(config_cls))
    add_config_arguments(parser, config_cls)
    return config_from_args(config_cls, parser.parse_args(argv))
