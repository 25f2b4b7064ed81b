"""The options' fixed sets of values (vision_rl.commands.choices) equal the library constants they mirror, and
argparse enforces them."""

from __future__ import annotations

import importlib

import pytest

from vision_rl.commands import choices
from vision_rl.commands.main import main


@pytest.mark.parametrize("name", [n for n in dir(choices) if n.isupper() and n != "POLICY_CHOICES"])
def test_each_set_of_values_is_the_library_constant(name):
    # the attribute docstring names the constant; read it from the source of the module
    source = importlib.import_module("vision_rl.commands.choices").__file__
    text = open(source, encoding="utf-8").read()
    path = text.split(f"\n{name} = ", 1)[1].split('"""', 2)[1]
    module, _, constant = path.rpartition(".")
    assert tuple(getattr(importlib.import_module(module), constant)) == getattr(choices, name)


@pytest.mark.parametrize(
    "argv",
    [
        ["train-policy", "--preset", "fast"],
        ["train-policy", "--steer-action", "wheel"],
        ["capture", "--compression", "bz2"],
        ["train-baseline", "--algo", "ppo"],
        ["train-ddpg", "--variant", "twin"],
        ["train-overtaking", "--agent", "4"],
    ],
)
def test_a_value_out_of_the_set_is_refused_by_the_parser(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert "invalid choice" in capsys.readouterr().err
