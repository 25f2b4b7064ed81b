"""The DDPG lanes in the docs parse and pass their checks, so that starting them does not fail hours later on a
misspelt option: issue 64's equal-compute study (docs/results/ddpg-equal-compute), the three variants over two seeds
at one equal training time, each in its own run folder, one lane each (the six share the cores equally); and the
state actor's screens (docs/results/ddpg-state-actor-catalunya-gt3/lanes), each training run timed after it."""

from __future__ import annotations

import os
import shlex
from pathlib import Path

from vision_rl.commands.main import parse_command

RESULTS = Path(__file__).parents[2] / "docs/results"
LANES = sorted((RESULTS / "ddpg-equal-compute").glob("*.txt"))
SCREENS = sorted((RESULTS / "ddpg-state-actor-catalunya-gt3/lanes").glob("*.txt"))


def _lines(lane: Path) -> list[list[str]]:
    return [shlex.split(line) for line in lane.read_text().splitlines() if line.strip() and not line.startswith("#")]


def test_the_lanes_run_each_variant_and_seed_once_at_one_training_time() -> None:
    lines = [words for lane in LANES for words in _lines(lane)]
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


def test_a_screen_lane_trains_a_state_actor_then_times_that_run():
    """Two screens of three training seeds each: the stuck end as a truncation, and Lillicrap et al.'s learning rates
    (each on the crash-goes-on task, one question each)."""
    runs = []
    for lane in SCREENS:
        (train, evaluate) = _lines(lane)
        run = parse_command("train-ddpg", [os.path.expanduser(w) for w in train[1:]])
        timing = parse_command("evaluate-ddpg", [os.path.expanduser(w) for w in evaluate[1:]])
        assert (train[0], evaluate[0], run.variant, timing.agent) == (
            "train-ddpg",
            "evaluate-ddpg",
            "state-actor",
            run.out,
        )
        assert not run.env.terminate_on_crash and run.env.crash_penalty_beta == 10.0
        runs.append(run)
    truncate = sorted(r.seed for r in runs if r.env.truncate_when_stuck and r.hyper.actor_lr == 1e-3)
    rates = sorted(
        r.seed for r in runs if not r.env.truncate_when_stuck and (r.hyper.actor_lr, r.hyper.critic_lr) == (1e-4, 1e-3)
    )
    assert truncate == rates == [0, 1, 2] and len({r.out for r in runs}) == 6
