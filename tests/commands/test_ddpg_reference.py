"""`vision-rl ddpg-reference`: the command goes from its runs' records to the summary and the figure (the records
are stand-ins here: training is tests/ddpg/test_reference.py's)."""

from __future__ import annotations

import json

from vision_rl.commands.main import main


def _record(run) -> dict:
    return {
        "task": run.task,
        "algo": run.algo,
        "seed": run.seed,
        "steps": run.steps,
        "train_time_s": 1.0,
        "final_return": -1.0,
        "episodes": [{"num_steps": run.steps, "return": -1.0, "length": run.steps}],
        "evaluations": [{"num_steps": run.steps, "mean_return": -1.0, "returns": [-1.0]}],
    }


def test_the_figure_bins_by_the_runs_evaluation_interval(monkeypatch, tmp_path, capsys):
    seen = {}

    def plot(records, path, bin_steps):
        seen["bin_steps"] = bin_steps
        return path

    monkeypatch.setattr("vision_rl.ddpg.reference.load_or_run", lambda run, out, force: (_record(run), True))
    monkeypatch.setattr("vision_rl.ddpg.reference.plot_reference", plot)
    argv = ["ddpg-reference", "--task", "MountainCarContinuous-v0", "--steps", "4000", "--eval-every-steps", "2000"]
    assert main([*argv, "--algos", "ours-bn,sb3-ddpg", "--seeds", "0,1", "--out", str(tmp_path), "--json"]) == 0
    assert seen == {"bin_steps": 2_000}
    summary = json.loads((tmp_path / "MountainCarContinuous-v0" / "summary.json").read_text())
    assert [(row["algo"], row["seeds"]) for row in summary["rows"]] == [("ours-bn", [0, 1]), ("sb3-ddpg", [0, 1])]
    assert json.loads(capsys.readouterr().out)["task"] == "MountainCarContinuous-v0"
