"""Command configs: one dataclass per command with a doc line per field (CleanRL style), turned into argparse."""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any


def doc(text: str, negative: str = "") -> dict[str, str]:
    """Field metadata carrying the field's help line: ``field(default=..., metadata=doc("..."))``.

    ``negative`` names an extra switch that sets a bool field to False (``--no-disrupt`` for ``disrupt_ai``).
    """
    return {"help": text, "negative": negative}


_TYPES = {"int": int, "float": float, "str": str}


def add_config_arguments(parser: argparse.ArgumentParser, config_cls: type) -> None:
    """One ``--option`` per field of ``config_cls`` (bools become ``--x/--no-x``)."""
    for f in dataclasses.fields(config_cls):
        flag = "--" + f.name.replace("_", "-")
        help_text = f.metadata.get("help", "")
        default = f.default if f.default is not dataclasses.MISSING else None
        kind = str(f.type).replace(" | None", "")
        if kind == "bool":
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=help_text)
            if f.metadata.get("negative"):
                parser.add_argument(
                    f.metadata["negative"], dest=f.name, action="store_false", help=f"same as --no-{flag[2:]}"
                )
            continue
        if kind not in _TYPES:
            raise TypeError(f"{config_cls.__name__}.{f.name}: command options must be int, float, str or bool")
        parser.add_argument(flag, type=_TYPES[kind], default=default, help=f"{help_text} (default: {default})")


def config_from_args(config_cls: type, args: argparse.Namespace) -> Any:
    return config_cls(**{f.name: getattr(args, f.name) for f in dataclasses.fields(config_cls)})
