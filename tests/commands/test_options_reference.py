"""Every command keeps its options: name, default, help line, choices and whether it is required, compared with the
reference in ``options_reference.json``. A change of the CLI on purpose regenerates the reference:
``python -m tests.commands.test_options_reference``."""

from __future__ import annotations

import argparse
import importlib
import inspect
import json
import sys
from pathlib import Path

from vision_rl.commands.main import COMMANDS
from vision_rl.commands.options import add_config_arguments

REFERENCE = Path(__file__).with_name("options_reference.json")


def command_options(name: str) -> list[dict]:
    command = COMMANDS[name]
    options_cls = getattr(importlib.import_module(command.module), command.options)
    parser = argparse.ArgumentParser(prog=f"vision-rl {name}", description=inspect.getdoc(options_cls))
    add_config_arguments(parser, options_cls)
    return [
        {
            "flags": list(action.option_strings),
            "dest": action.dest,
            "default": repr(action.default),
            "help": " ".join((action.help or "").split()),
            "choices": None if action.choices is None else [repr(c) for c in action.choices],
            "required": bool(action.required),
        }
        for action in parser._actions
        if not isinstance(action, argparse._HelpAction)
    ]


def all_options() -> dict[str, list[dict]]:
    return {name: command_options(name) for name in sorted(COMMANDS)}


def by_flags(options: list[dict]) -> dict[str, dict]:
    """Options keyed by their flags: the order they are listed in is not part of the interface."""
    return {" ".join(option["flags"]) or option["dest"]: option for option in options}


def test_every_command_keeps_its_options():
    reference = json.loads(REFERENCE.read_text(encoding="utf-8"))
    now = all_options()
    assert sorted(now) == sorted(reference)
    for name in reference:
        assert by_flags(now[name]) == by_flags(reference[name]), name


if __name__ == "__main__":
    REFERENCE.write_text(json.dumps(all_options(), indent=1) + "\n", encoding="utf-8")
    sys.exit(0)
