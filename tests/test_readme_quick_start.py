"""The README's quick start runs as written, shrunk: a few SAC steps on a small track instead of 200,000 on the
expressway, then the agent is timed by vision_rl.evaluate and listed by the leaderboard."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def quick_start() -> str:
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Quick start") :]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.mark.slow
def test_the_quick_start_runs_and_its_agent_reaches_the_leaderboard(small_track, tmp_path, monkeypatch, capsys):
    code = quick_start()
    assert "vision_rl.evaluate(" in code and "total_timesteps=200_000" in code
    code = code.replace('track="expressway"', f"track={small_track!r}").replace("200_000", "300")
    monkeypatch.chdir(tmp_path)
    exec(compile(code, str(README), "exec"), {"__name__": "quick_start"})
    lap, where = capsys.readouterr().out.split()
    assert lap == "None" or float(lap) > 0  # a few hundred steps seldom lap
    record = json.loads(Path(where).read_text())
    assert record["name"] == "my-sac" and Path(where).resolve().parent == tmp_path.resolve() / "runs" / "my-sac"

    from vision_rl.commands.evaluate import LeaderboardOptions, run_leaderboard

    assert run_leaderboard(LeaderboardOptions(track=small_track, car="hatchback", runs="runs", json=True)) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert "my-sac" in [row.get("name") for row in rows]
