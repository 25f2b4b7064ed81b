"""Options from config dataclasses: help from attribute docstrings (the bases' too), bools, pairs, extra switches."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
from dataclasses import dataclass, field
from typing import ClassVar

import pytest

from vision_rl.commands.options import add_config_arguments, config_from_args, field_docs, parse_config


@dataclass(frozen=True)
class LibraryConfig:
    """A library config: docstrings only, nothing from the command layer."""

    speed_mps: float = 2.0
    """Target speed, m/s;
    on two lines."""
    image_hw_px: tuple[int, int] = (280, 470)
    """Frame height and width, px."""
    disrupt_ai: bool = True
    """Disrupt the AI."""


@dataclass(frozen=True)
class CommandOptions(LibraryConfig):
    """A command's options: the library config plus output options."""

    negative_switches: ClassVar[dict[str, str]] = {"disrupt_ai": "--no-disrupt"}

    json: bool = False
    """Print JSON."""


@dataclass
class MetadataConfig:
    laps: int = field(default=1, metadata={"help": "laps to drive"})
    disrupt: bool = field(default=False, metadata={"help": "disrupt", "negative": "--calm"})


def _help(cls) -> str:
    parser = argparse.ArgumentParser(prog="x")
    add_config_arguments(parser, cls)
    return " ".join(parser.format_help().split())


def test_help_comes_from_the_attribute_docstrings_of_the_class_and_its_bases():
    assert field_docs(CommandOptions) == {
        "speed_mps": "Target speed, m/s; on two lines.",
        "image_hw_px": "Frame height and width, px.",
        "disrupt_ai": "Disrupt the AI.",
        "json": "Print JSON.",
    }
    text = _help(CommandOptions)
    assert "Target speed, m/s; on two lines (default: 2.0)" in text and "Print JSON" in text
    assert "laps to drive (default: 1)" in _help(MetadataConfig)  # metadata help, the fallback


def test_options_parse_into_the_config():
    opts = parse_config(CommandOptions, ["--speed-mps", "3", "--image-hw-px", "140", "236", "--no-disrupt", "--json"])
    assert opts == CommandOptions(speed_mps=3.0, image_hw_px=(140, 236), disrupt_ai=False, json=True)
    assert parse_config(CommandOptions, []) == CommandOptions()
    assert not parse_config(CommandOptions, ["--no-disrupt-ai"]).disrupt_ai
    assert parse_config(MetadataConfig, ["--disrupt", "--calm"]).disrupt is False


def test_an_option_type_the_command_line_cannot_express_is_refused():
    @dataclass
    class Bad:
        names: list = field(default_factory=list)

    with pytest.raises(TypeError, match=r"Bad\.names"):
        add_config_arguments(argparse.ArgumentParser(), Bad)


def test_the_command_configs_fit_the_plumbing():
    from vision_rl.commands.bench_latency import BenchLatencyOptions
    from vision_rl.commands.train_repr import TrainReprOptions

    argv = ["--data", "a.h5,b.h5", "--val", "e.h5", "--epochs", "3", "--lr", "0.01", "--no-augment", "--resume"]
    cfg = parse_config(TrainReprOptions, argv)
    assert cfg.data == "a.h5,b.h5" and cfg.epochs == 3 and cfg.lr == 0.01 and not cfg.augment and cfg.resume
    bench = parse_config(BenchLatencyOptions, ["--device", "cpu", "--image-hw-px", "64", "96", "--json"])
    assert bench.image_hw_px == (64, 96) and bench.json and bench.runs >= 200
    parser = argparse.ArgumentParser()
    add_config_arguments(parser, TrainReprOptions)
    assert config_from_args(TrainReprOptions, parser.parse_args([])) == TrainReprOptions()


def test_every_config_of_these_commands_is_frozen_with_a_docstring_per_field():
    from vision_rl.capture.sim_capture import CaptureConfig
    from vision_rl.commands.main import COMMANDS
    from vision_rl.phase1_repr.config import BenchLatencyConfig, TrainReprConfig

    mine = [c for c in COMMANDS.values() if c.module.startswith("vision_rl.commands.")]
    classes = [CaptureConfig, BenchLatencyConfig, TrainReprConfig]
    classes += [getattr(importlib.import_module(c.module), c.options) for c in mine]
    for cls in classes:
        missing = {f.name for f in dataclasses.fields(cls)} - set(field_docs(cls))
        assert not missing, f"{cls.__name__}: {missing}"
        assert cls.__dataclass_params__.frozen, cls.__name__


@dataclass(frozen=True)
class SwitchesConfig:
    quick: bool = False
    """Small job."""
    progress: bool = True
    """Show a bar."""
    disrupt_ai: bool = True
    """Disrupt the AI."""
    algo: str = field(default="sac", metadata={"choices": ("sac", "td3")})
    """Algorithm."""
    track: str = "expressway"
    """Track."""
    out: str = ""
    """Output file (required)."""
    encoder: str = ""
    """Encoder; empty: the state."""

    positive_switches: ClassVar[tuple[str, ...]] = ("disrupt_ai",)
    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"track": ("expressway", "technical")}


def test_booleans_have_no_meaningless_twin_and_choices_and_required_are_enforced(capsys):
    parser = argparse.ArgumentParser(prog="x")
    add_config_arguments(parser, SwitchesConfig)
    flags = {flag for action in parser._actions for flag in action.option_strings}
    assert {"--quick", "--no-progress", "--disrupt-ai", "--no-disrupt-ai"} <= flags
    assert not {"--no-quick", "--progress"} & flags
    opts = parse_config(SwitchesConfig, ["--out", "a.h5", "--quick", "--no-progress", "--algo", "td3"])
    assert opts.quick and not opts.progress and opts.disrupt_ai and opts.algo == "td3" and opts.out == "a.h5"
    for argv in (["--out", "a.h5", "--algo", "ppo"], ["--out", "a.h5", "--track", "moon"], ["--quick"]):
        with pytest.raises(SystemExit):
            parse_config(SwitchesConfig, argv)
    err = capsys.readouterr().err
    assert "invalid choice: 'ppo'" in err and "invalid choice: 'moon'" in err and "--out" in err
    text = _help(SwitchesConfig)
    assert "{sac,td3}" in text and "{expressway,technical}" in text and "(default: )" not in text
    assert "Encoder; empty: the state" in text and "Algorithm (default: sac)" in text


@dataclass(frozen=True)
class BoundsConfig:
    option_minimums: ClassVar[dict[str, float | None]] = {"offset_m": None}

    laps: int = 2
    """Laps."""
    max_steps: int = field(default=-1, metadata={"min": -1})
    """Steps (-1: no limit)."""
    share: float = field(default=0.5, metadata={"max": 1.0})
    """A share."""
    offset_m: float = 0.0
    """An offset of either sign, m."""


def test_numbers_are_finite_and_within_their_declared_bounds(capsys):
    opts = parse_config(BoundsConfig, ["--max-steps", "-1", "--offset-m", "-2.5", "--share", "1"])
    assert (opts.max_steps, opts.offset_m, opts.share) == (-1, -2.5, 1.0)
    refusals = {
        ("--laps", "-1"): "argument --laps: -1 is below the least value, 0",
        ("--laps", "2.5"): "argument --laps: '2.5' is not an integer",
        ("--max-steps", "-2"): "argument --max-steps: -2 is below the least value, -1",
        ("--share", "1.5"): "argument --share: 1.5 is above the greatest value, 1",
        ("--share", "nan"): "argument --share: 'nan' is not a finite number",
        ("--offset-m", "inf"): "argument --offset-m: 'inf' is not a finite number",
        ("--offset-m", "east"): "argument --offset-m: 'east' is not a number",
    }
    for argv, message in refusals.items():
        with pytest.raises(SystemExit):
            parse_config(BoundsConfig, list(argv))
        assert message in capsys.readouterr().err, argv


def test_size_options_are_priced_against_the_memory_budget(monkeypatch):
    from vision_rl.budget import BUDGET_ENV, MemoryBudgetError
    from vision_rl.commands.options import check_memory

    monkeypatch.setenv(BUDGET_ENV, "1")
    check_memory({"cars": 20, "buffer_size": 1_000_000, "image_hw_px": (280, 470), "hidden_units": "256,256"})
    for values, refused in (
        ({"cars": 2_000}, "--cars 2000"),
        ({"workers": 3}, "--workers 3"),
        ({"batch_sizes": (64, 2_000_000)}, "--batch-sizes 2000000"),
        ({"cars": 300, "image_hw_px": (280, 470)}, "--image-hw-px 280 470"),  # 300 cars' frames: 1.3 GB
        ({"hidden_units": "4096,4096,4096"}, "--hidden-units 4096,4096,4096"),
        ({"image_hw_px": (280, 470), "batch_size": 1_000}, "--batch-size 1000"),  # frames: 6.3 GB
    ):
        with pytest.raises(MemoryBudgetError, match=f"^{refused} needs about"):
            check_memory(values)
    check_memory({"batch_size": 1_000})  # 1,000 state samples
    check_memory({"workers": 3, "address": "ray://head:10001"})  # samplers on a cluster use its machines' memory


def test_every_path_of_a_comma_separated_list_has_its_tilde_expanded(monkeypatch, tmp_path):
    from vision_rl.commands.options import comma_list, comma_paths

    monkeypatch.setenv("HOME", str(tmp_path))
    # `--curves ~/a,~/b`: the shell expands the first ~ only.
    assert comma_paths(f"{tmp_path}/a, ~/b,,") == [f"{tmp_path}/a", f"{tmp_path}/b"]
    assert comma_list(" 1, 2 ,", int) == [1, 2]
