"""Command-line options from config dataclasses: one ``--option`` per leaf field, its help from the field's docstring.

A field's help is its attribute docstring (:func:`vision_rl.config.field_docs`), or the word of the config that holds
it; a held config's fields appear flat (:func:`vision_rl.config.flat_fields`). A bool that is off by default becomes
``--x``; one that is on by default becomes ``--no-x`` (and ``--x`` too when the config lists it in
``positive_switches``, a form a command line may state); a config may name extra switches that set a bool to False in
``negative_switches`` (``{"disrupt_ai": "--no-disrupt"}``) or a field's ``metadata={"negative": ...}``. A field with a
fixed set of values names them in ``metadata={"choices": (...)}`` or the config's ``option_choices`` (``{"algo":
ALGOS}``); argparse shows and enforces them. A field whose help ends with "(required)" is required. An empty default
(``""``, None) shows no default text: the help says what empty means.
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


def _add_bool(parser: argparse.ArgumentParser, flat: Any, help_text: str, config_cls: type) -> None:
    """``--x`` for a bool off by default, ``--no-x`` (and ``--x`` when listed) for one on by default."""
    flag = "--" + flat.name.replace("_", "-")
    if not flat.default:
        parser.add_argument(flag, dest=flat.name, action="store_true", help=help_text)
    else:
        if flat.name in getattr(config_cls, "positive_switches", ()):
            parser.add_argument(flag, dest=flat.name, action="store_true", default=True, help=f"{help_text} (default)")
        no_help = f"off: {help_text[0].lower()}{help_text[1:]} (on by default)" if help_text else None
        parser.add_argument("--no-" + flag[2:], dest=flat.name, action="store_false", default=True, help=no_help)
    negative = dict(getattr(config_cls, "negative_switches", {})).get(flat.name) or flat.field.metadata.get("negative")
    if negative:
        parser.add_argument(negative, dest=flat.name, action="store_false", help=f"same as --no-{flag[2:]}")


def _choices(flat: Any, config_cls: type) -> tuple | None:
    named = flat.field.metadata.get("choices") or dict(getattr(config_cls, "option_choices", {})).get(flat.name)
    return tuple(named) if named else None


def _default_text(default: Any) -> str:
    """`` (default: 3)``, or nothing for an empty default (the help says what empty means)."""
    if default is None or default == "" or default == ():
        return ""
    shown = " ".join(map(str, default)) if isinstance(default, tuple) else default
    return f" (default: {shown})"


def add_config_arguments(parser: argparse.ArgumentParser, config_cls: type) -> None:
    """One ``--option`` per leaf field of ``config_cls`` and of the configs it holds (:func:`flat_fields`)."""
    leaves = flat_fields(config_cls)
    flags = {flat.path[-1]: flat.name for flat in leaves} | {flat.name: flat.name for flat in leaves}

    def as_option(match: re.Match) -> str:  # ``laps`` in a docstring reads --laps on the command line
        word = match.group(1)
        return "--" + flags[word].replace("_", "-") if word in flags else word

    for flat in leaves:
        flag = "--" + flat.name.replace("_", "-")
        help_text = re.sub(r"``(\w+)``", as_option, flat.doc).rstrip(".")
        default, kind = flat.default, _type_name(flat.field.type)
        required = help_text.endswith("(required)")
        if kind == "bool":
            _add_bool(parser, flat, help_text, config_cls)
            continue
        if kind not in _SCALARS and kind not in _TUPLES:
            raise TypeError(f"{config_cls.__name__}.{flat.name}: options must be int, float, str, bool or a tuple")
        item, n = (_SCALARS[kind], None) if kind in _SCALARS else _TUPLES[kind]
        metavar = ("HEIGHT", "WIDTH") if flat.name.endswith("hw_px") else None
        parser.add_argument(
            flag,
            dest=flat.name,
            type=item,
            nargs=n,
            metavar=metavar,
            choices=_choices(flat, config_cls),
            required=required,
            default=None if required else default,
            help=help_text + ("" if required else _default_text(default)),
        )


def config_from_args(config_cls: type, args: argparse.Namespace) -> Any:
    """The config built from parsed options (lists of ``nargs`` options become tuples)."""
    values = {flat.name: getattr(args, flat.name) for flat in flat_fields(config_cls)}
    return from_flat(config_cls, {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def parse_config(config_cls: type, argv: list[str], prog: str | None = None) -> Any:
    """Parse ``argv`` into a ``config_cls``; the parser's description is the class docstring."""
    parser = argparse.ArgumentParser(prog=prog, description=inspect.getdoc(config_cls))
    add_config_arguments(parser, config_cls)
    return config_from_args(config_cls, parser.parse_args(argv))
