"""The lanes of issue 64's equal-compute study (docs/results/ddpg-equal-compute): every line is a train-ddpg command
that parses and passes its checks, the three variants over two seeds at one equal training time, each in its own
run folder, one lane each (the six share the cores equally), so that starting the lanes does not fail hours later
on a misspelt option."""

from __future__ import annotations

import os
import shlex
from pathlib import Path

from vision_rl.commands.main import parse_command

LANES = sorted((Path(__file__).parents[2] / "docs/results/ddpg-equal-compute").glob("*.txt"))


def test_the_lanes_run_each_variant_and_seed_once_at_one_training_time() -> None:
    lines = [
        shlex.split(line)
        for lane in LANES
        for line in lane.read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    assert len(lines) == len(LANES) == 6 and all(words[0] == "train-ddpg" for words in lines)
    runs = [parse_command("train-ddpg", [os.path.expanduser(w) for w in words[1:]]) for words in lines]
    assert sorted((r.variant, r.seed) for r in runs) == sorted(
        (v, s) for v in ("asymmetric", "symmetric", "state-actor") for s in (0, 1)
    )
    assert {r.train_minutes for r in runs} == {200.0} and len({r.out for r in runs}) == len(runs)
    assert {(r.env.terminate_on_crash, r.env.crash_penalty_beta, r.env.max_line_distance_m) for r in runs} == {
        (False, 10.0, 15.0)
    }
    assert all(r.hyper.trunk == "cpu" for r in runs if r.variant != "state-actor")
