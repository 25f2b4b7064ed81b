"""Command-line options from config dataclasses: one ``--option`` per field, its help from the field's docstring.

A field's help is its attribute docstring, the string literal right after it in the class body (read with
:mod:`ast` from the source of the class and of its dataclass bases, so a library config needs nothing from this
package); ``metadata={"help": ...}`` is the fallback. Bools become ``--x/--no-x``; a config may name extra switches
that set a bool to False in a ``negative_switches`` class attribute (``{"disrupt_ai": "--no-disrupt"}``; the older
``metadata={"negative": ...}`` works too). Field types: int, float, str, bool, ``tuple[int, int]`` (two values
after the option, e.g. ``--image-hw-px 140 236``) and ``tuple[int, ...]`` / ``tuple[str, ...]`` (one or more).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import re
import textwrap
from typing import Any

_SCALARS = {"int": int, "float": float, "str": str}
_TUPLES = {
    "tuple[int, int]": (int, 2),
    "tuple[float, float]": (float, 2),
    "tuple[int, ...]": (int, "+"),
    "tuple[str, ...]": (str, "+"),
}


def field_docs(config_cls: type) -> dict[str, str]:
    """Field name -> attribute docstring (one line), over the class and its dataclass bases (the subclass wins)."""
    docs: dict[str, str] = {}
    for klass in reversed(config_cls.__mro__):
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):  # no source (built at run time): metadata help only
            continue
        node = tree.body[0]
        if not isinstance(node, ast.ClassDef):
            continue
        for stmt, after in zip(node.body, node.body[1:], strict=False):
            if (
                isinstance(stmt, ast.AnnAssign)
                and isinstance(stmt.target, ast.Name)
                and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                docs[stmt.target.id] = " ".join(after.value.value.split())
    return docs


def _type_name(annotation: Any) -> str:
    """``"int"``, ``"tuple[int, int]"``... from a string annotation or a type, ``| None`` dropped."""
    name = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", None) or str(annotation)
    return " ".join(name.replace("typing.", "").replace(" | None", "").split())


def add_config_arguments(parser: argparse.ArgumentParser, config_cls: type) -> None:
    """One ``--option`` per field of ``config_cls``."""
    docs = field_docs(config_cls)
    names = {f.name for f in dataclasses.fields(config_cls)}
    negatives = dict(getattr(config_cls, "negative_switches", {}))

    def as_option(match: re.Match) -> str:  # ``laps`` in a docstring reads --laps on the command line
        word = match.group(1)
        return "--" + word.replace("_", "-") if word in names else word

    for f in dataclasses.fields(config_cls):
        flag = "--" + f.name.replace("_", "-")
        help_text = re.sub(r"``(\w+)``", as_option, docs.get(f.name) or f.metadata.get("help", "")).rstrip(".")
        default = f.default if f.default is not dataclasses.MISSING else None
        kind = _type_name(f.type)
        if kind == "bool":
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=help_text)
            negative = negatives.get(f.name) or f.metadata.get("negative")
            if negative:
                parser.add_argument(negative, dest=f.name, action="store_false", help=f"same as --no-{flag[2:]}")
        elif kind in _SCALARS:
            parser.add_argument(flag, type=_SCALARS[kind], default=default, help=f"{help_text} (default: {default})")
        elif kind in _TUPLES:
            item, n = _TUPLES[kind]
            shown = " ".join(map(str, default)) if default is not None else None
            metavar = ("HEIGHT", "WIDTH") if f.name.endswith("hw_px") else None
            parser.add_argument(
                flag, type=item, nargs=n, metavar=metavar, default=default, help=f"{help_text} (default: {shown})"
            )
        else:
            raise TypeError(f"{config_cls.__name__}.{f.name}: options must be int, float, str, bool or a tuple")


def config_from_args(config_cls: type, args: argparse.Namespace) -> Any:
    """The config built by keyword from parsed options (lists of ``nargs`` options become tuples)."""
    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(config_cls)}
    return config_cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def parse_config(config_cls: type, argv: list[str], prog: str | None = None) -> Any:
    """Parse ``argv`` into a ``config_cls``; the parser's description is the class docstring."""
    parser = argparse.ArgumentParser(prog=prog, description=inspect.getdoc(config_cls))
    add_config_arguments(parser, config_cls)
    return config_from_args(config_cls, parser.parse_args(argv))
