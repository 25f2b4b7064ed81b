"""Options: every number option of every command given a negative number, NaN, infinity, a word and an absurd
size; the issue's oversized requests and silent acceptances; the memory budget and its override. Each is refused
in one line before anything is built, and a refused oversized request stays small in memory."""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from vision_rl.budget import BUDGET_ENV, MemoryBudgetError, memory_budget, require_memory
from vision_rl.commands.main import COMMANDS, main, parse_command
from vision_rl.config import flat_fields

BAD_VALUES = {"-1": "-1", "nan": "NaN", "inf": "inf", "word": "a word", "1000000000000": "1e12"}
#: Options where a negative value means something (the option's help says what).
NEGATIVE_MEANS_SOMETHING = {
    "max_steps": "-1: no limit",
    "learning_starts": "-1: the preset's",
    "target_entropy": "an entropy target, nats, is negative",
    "analysis_run": "-1: the fastest run",
}
#: Numbers that size no memory, so 1e12 of them is slow or odd but allocates nothing: counts of work (steps,
#: epochs, repeats), durations, distances, seeds and coefficients.
NOT_A_MEMORY_SIZE = {
    # counts of work: time, not memory
    *("steps", "epochs", "train_epochs", "bc_max_epochs", "bc_patience", "repeats", "warmup", "updates", "trials"),
    *("updates_per_step", "gradient_steps", "gail_disc_updates", "max_staleness", "version_every_updates"),
    *("eval_every_steps", "checkpoint_every_steps", "gail_disc_every_steps", "dreamer_train_every_steps"),
    *("stage1_max_steps", "stage2_steps", "stage3_steps", "standard_steps", "guide_steps", "prune_after_steps"),
    *("max_steps", "learning_starts", "capture_frames", "max_frames"),  # frames go to disk, not memory
    # durations, distances, seeds
    *("episode_s", "eval_episode_s", "time_limit_s", "eval_time_limit_s", "flush_interval_s", "sampling_seconds"),
    *("checkpoint_every_min", "train_minutes", "bin_minutes"),
    *("sections_m", "reward_bin_m", "lead_margin_m", "detection_range_c_d_m", "max_line_distance_m"),
    *("restart_before_stuck_m", "seed", "sampler_seed", "analysis_run"),  # a run index: refused past --runs
    # coefficients and rates
    *("lr", "actor_lr", "critic_lr", "learning_rate", "learning_rate_final", "gail_disc_lr", "weight_decay"),
    *("wall_penalty_c_w", "steer_change_penalty_c_s", "off_track_penalty_c_o", "overtake_gain_c_r", "wall_weight"),
    *("guide_label_weight", "crash_penalty_beta", "line_distance_alpha", "reward_scale", "stage1_margin"),
    *("noise", "td3_noise", "ou_sigma", "ou_theta", "disrupt_steer_offset_rad", "fps"),
}


def _options_cls(name: str) -> type:
    return getattr(importlib.import_module(COMMANDS[name].module), COMMANDS[name].options)


def _number_options(name: str) -> list[tuple[str, int]]:
    """(flat name, values the option takes: 1, or 2 for a frame size) of every int or float option."""
    out = []
    for flat in flat_fields(_options_cls(name)):
        kind = str(flat.field.type).replace(" | None", "")
        if kind in ("int", "float") or kind.startswith(("tuple[int", "tuple[float")):
            out.append((flat.name, 2 if kind in ("tuple[int, int]", "tuple[float, float]") else 1))
    return out


def _required(name: str) -> list[str]:
    return [
        arg
        for flat in flat_fields(_options_cls(name))
        if flat.doc.rstrip(".").endswith("(required)")
        for arg in ("--" + flat.name.replace("_", "-"), "x")
    ]


def _outcome(name: str, argv: list[str]) -> tuple[str, str]:
    """("refused", the one line) or ("accepted", "") for parsing and checking ``argv``; nothing runs. Any other
    exception (a traceback) fails the test."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            parse_command(name, argv)
    except SystemExit as stop:
        lines = err.getvalue().strip().splitlines()
        assert stop.code == 2 and lines and lines[-1].startswith(f"vision-rl {name}: error: "), err.getvalue()
        return "refused", lines[-1]
    except ValueError as exc:
        assert "\n" not in str(exc).strip(), f"{name} {argv}: refused in more than one line: {exc}"
        return "refused", str(exc)
    return "accepted", ""


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_number_option_refuses_bad_values_in_one_line(name, fault):
    """Generated: each number option of the command given -1, NaN, inf, a word and 1e12, parsed and checked in
    this process (no training); refused in one line unless the value means something there."""
    base = _required(name)
    accepted, example = [], ""
    for option, n_values in _number_options(name):
        for bad in BAD_VALUES:
            flag = "--" + option.replace("_", "-")
            outcome, line = _outcome(name, [*base, flag, bad, *(["100"] * (n_values - 1))])
            example = example or line
            meaningful = (bad == "-1" and option in NEGATIVE_MEANS_SOMETHING) or (
                bad == "1000000000000" and option in NOT_A_MEMORY_SIZE
            )
            if outcome == "accepted" and not meaningful:
                accepted.append(f"{flag} {bad}")
    assert not accepted, f"{name} accepted silently: {accepted}"
    if example:
        fault.refused(f"{name}: each number option given -1, NaN, inf, a word, 1e12", example)


def test_every_command_is_walked():
    """The walk above covers every command and hundreds of options (a parser it cannot read would fail here)."""
    total = sum(len(_number_options(name)) for name in COMMANDS)
    assert total > 250


def _refused(argv: list[str], capsys) -> str:
    """The one stderr line of a refused command (exit 2, by argparse or the project's checks); nothing ran."""
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert "Traceback" not in err
    return err.splitlines()[-1]


def _circle_csv(path: Path, radius_m: float, width_m: float) -> str:
    points = [
        f"{radius_m * math.cos(2 * math.pi * k / 200):.3f},{radius_m * math.sin(2 * math.pi * k / 200):.3f},"
        f"{width_m},{width_m}"
        for k in range(200)
    ]
    path.write_text("\n".join(points) + "\n")
    return str(path)


OVERSIZED = {
    "a CSV track of radius 2,000 km": (["limit", "--track", "{huge}"], "needs about"),
    "track widths of 1e6 m": (["limit", "--track", "{wide}"], "track widths up to 1,000,000 m"),
    "train-repr --num-workers 100000": (["train-repr", "--data", "a.h5", "--num-workers", "100000"], "--num-workers"),
    "train-policy --buffer-size 1e12": (["train-policy", "--buffer-size", "1000000000000"], "--buffer-size"),
    "train-policy --hidden-units 100000,100000": (
        ["train-policy", "--hidden-units", "100000,100000"],
        "--hidden-units 100000,100000 needs about",
    ),
    "train-policy --batch-size 1e9": (["train-policy", "--batch-size", "1000000000"], "--batch-size"),
    "train-repr --width-mult 10000": (["train-repr", "--data", "a.h5", "--width-mult", "10000"], "--width-mult"),
    "evaluate --seeds 1000000": (["evaluate", "--policy", "x", "--seeds", "1000000"], "--seeds 1000000 needs about"),
    "capture --image-hw-px 100000 100000": (
        ["capture", "--out", "x.h5", "--image-hw-px", "100000", "100000"],
        "--image-hw-px",
    ),
}


@pytest.mark.parametrize("what", list(OVERSIZED))
def test_an_oversized_request_is_refused_before_it_allocates(what, tmp_path, capsys, monkeypatch, fault):
    monkeypatch.setenv(BUDGET_ENV, "16")  # a machine of about 20 GB, whatever this one has
    argv, expected = OVERSIZED[what]
    files = {"huge": _circle_csv(tmp_path / "huge.csv", 2e6, 6), "wide": _circle_csv(tmp_path / "wide.csv", 2e3, 1e6)}
    line = _refused([arg.format(**files) for arg in argv], capsys)
    assert expected in line and ("over the budget" in line or "is out of range" in line or "than" in line), line
    fault.refused(what, line)


SILENT_BEFORE = {
    "train-repr --val equal to --data": (["train-repr", "--data", "a.h5", "--val", "./a.h5"], "is also in --data"),
    "train-repr --shift-px 100000": (["train-repr", "--data", "a.h5", "--shift-px", "100000"], "--shift-px 100000"),
    "evaluate --time-limit-s -1": (["evaluate", "--policy", "x", "--time-limit-s", "-1"], "below the least value"),
    "evaluate --time-limit-s nan": (["evaluate", "--policy", "x", "--time-limit-s", "nan"], "not a finite number"),
    "train-policy --seed -1": (["train-policy", "--seed", "-1"], "argument --seed: -1 is below the least value"),
    "drive --skill 2": (["drive", "--skill", "2"], "above the greatest value"),
    "curves without --files": (["curves"], "required: --files"),
    "convert-policy without --run": (["convert-policy"], "required: --run"),
    "evaluate-ddpg without --agent": (["evaluate-ddpg"], "required: --agent"),
    "compare-ddpg without --runs": (["compare-ddpg"], "required: --runs"),
    # Durations of 1e308 s overflowed the step counts made from them (OverflowError tracebacks) or were kept.
    "train-policy --episode-s 1e308": (["train-policy", "--episode-s", "1e308"], "above the greatest value"),
    "evaluate --time-limit-s 1e308": (["evaluate", "--policy", "x", "--time-limit-s", "1e308"], "greatest value"),
    "evaluate-ddpg --time-limit-s 1e308": (
        ["evaluate-ddpg", "--agent", "x", "--time-limit-s", "1e308"],
        "above the greatest value",
    ),
    "train-policy --checkpoint-every-min 1e308": (
        ["train-policy", "--checkpoint-every-min", "1e308"],
        "above the greatest value, 525600",
    ),
}


@pytest.mark.parametrize("what", list(SILENT_BEFORE))
def test_a_value_once_accepted_silently_is_refused(what, capsys, fault):
    argv, expected = SILENT_BEFORE[what]
    line = _refused(argv, capsys)
    assert expected in line, line
    fault.refused(what, line)


@pytest.mark.parametrize("command", ["train-policy", "train-repr"])
def test_a_cuda_device_on_a_machine_without_one_is_refused(command, capsys, fault):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    data = ["--data", "a.h5"] if command == "train-repr" else []
    line = _refused([command, *data, "--device", "cuda"], capsys)
    assert "--device cuda: torch sees no CUDA GPU here" in line, line
    fault.refused(f"{command} --device cuda without a GPU", line)


def test_the_budget_is_overridable_and_its_override_checked(monkeypatch, capsys, fault):
    monkeypatch.setenv(BUDGET_ENV, "0.5")
    assert memory_budget()[0] == 0.5e9
    line = _refused(["train-policy", "--buffer-size", "10000000"], capsys)  # 1 GB at the floor of 100 B a row
    assert f"over the budget of 0.5 GB (set by {BUDGET_ENV}=0.5)" in line, line
    fault.refused(f"{BUDGET_ENV}=0.5 and train-policy --buffer-size 10000000", line)
    monkeypatch.setenv(BUDGET_ENV, "lots")
    line = _refused(["drive", "--seeds", "3"], capsys)
    assert f"{BUDGET_ENV}='lots' is not a positive number of GB" in line, line
    fault.refused(f"{BUDGET_ENV}=lots", line)
    monkeypatch.delenv(BUDGET_ENV)
    with pytest.raises(MemoryBudgetError, match="nan bytes"):
        require_memory("a NaN size", math.nan)
    require_memory("a small request", 1e6)


# A refused request measured from outside: the peak memory of the command's own process (RUSAGE_CHILDREN of a
# wrapper that runs only it).
_PEAK = """
import resource, subprocess, sys
run = subprocess.run([sys.executable, "-m", "vision_rl.commands.main", *sys.argv[1:]], capture_output=True, text=True)
print(run.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, repr(run.stderr.strip()[-200:]))
"""


def test_refused_oversized_requests_stay_under_1_gb(tmp_path, fault):
    huge = _circle_csv(tmp_path / "huge.csv", 2e6, 6)
    peaks = {}
    for argv in (
        ["limit", "--track", huge],
        ["train-policy", "--buffer-size", "1000000000000"],
        ["train-repr", "--data", "a.h5", "--num-workers", "100000"],
        ["evaluate", "--policy", "x", "--seeds", "1000000"],
    ):
        run = subprocess.run([sys.executable, "-c", _PEAK, *argv], capture_output=True, text=True, timeout=120)
        code, peak_kb, err = run.stdout.split(" ", 2)
        assert code == "2" and "Traceback" not in err, err
        peaks[f"{argv[0]} {argv[-2]}"] = int(peak_kb) / 1024
    assert max(peaks.values()) < 1024, peaks
    fault.recovered(
        "peak memory of refused oversized requests (track, buffer, workers, seeds)",
        "refused in one line with at most "
        + json.dumps({k.replace(huge, "huge.csv"): round(v) for k, v in peaks.items()})
        + " MB of peak memory",
    )
