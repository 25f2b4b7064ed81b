"""compare-ddpg on hand-made run folders: runs cut at the common training time, bin means, the first lap (its
refusals: tests/faults/test_ddpg.py)."""

from __future__ import annotations

import pytest

from tests.helpers.ddpg import hand_made_run
from vision_rl.ddpg.compare import compare_runs, plot_comparison


def test_runs_are_cut_at_the_common_time_and_binned(tmp_path):
    a_episodes = [(1, 100, 0), (4, 300, 0), (12, 500, 0), (25, 5000, 1), (29, 900, 0), (30, 700, 0)]
    a = hand_made_run(tmp_path / "a", "asymmetric", 30.0, a_episodes)
    # Trained 40 minutes: its episodes after minute 30 are not compared.
    s_episodes = [(2, 50, 0), (21, 150, 0), (28, 250, 0), (35, 9000, 1)]
    s = hand_made_run(tmp_path / "s", "symmetric", 40.0, s_episodes, updates=1200, cpu_minutes=13.5)
    result = compare_runs([a, s], bin_min=10.0)
    assert result["common_minutes"] == 30.0 and result["bin_start_minutes"] == [0.0, 10.0, 20.0]
    ra, rs = result["runs"]
    # The episode ending at the common minute 30 counts in the last bin.
    assert ra["name"] == "asymmetric s1" and ra["bin_mean_distance_m"] == [200.0, 500.0, 2200.0]
    assert ra["bin_episodes"] == [2, 1, 3] and ra["mean_distance_last_m"] == 2200.0  # minutes 20-30
    assert ra["reward_per_step_last"] == 220.0 and ra["ends_last"] == {"crash 2": 3}  # 6,600 over 30 steps
    assert ra["first_lap_episode"] == 4 and ra["first_lap_minutes"] == 25.0 and ra["best_distance_m"] == 5000.0
    assert rs["episodes"] == 3 and rs["bin_mean_distance_m"] == [50.0, None, 200.0]
    assert rs["first_lap_episode"] is None and rs["best_distance_m"] == 250.0
    assert ra["updates_per_s"] == pytest.approx(600 / 1800) and rs["updates_per_s"] == pytest.approx(1200 / 2400)
    assert ra["train_cpu_minutes"] is None and rs["train_cpu_minutes"] == 13.5  # a run's own CPU time, not cut
    png = plot_comparison(result, tmp_path / "fig.png")
    assert png.stat().st_size > 5000
