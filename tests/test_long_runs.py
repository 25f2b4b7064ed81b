"""scripts/long_runs.sh with a stand-in for vision-rl: a line runs chunk after chunk until it exits 0, and a trainer
that continues a run only when asked (train-ddpg refuses a folder holding a run without --resume) gets --resume, so
that the same lane file serves a fresh start, the chunks after the first and a restart after the machine stopped."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "long_runs.sh"

#: Stands in for `python -m vision_rl.commands.main LINE --no-progress`: refuses a folder holding a run without
#: --resume as train-ddpg does, counts its chunks in the folder, and times out (124) until its third chunk;
#: evaluate-ddpg, which has no progress bar, refuses --no-progress as argparse does.
STAND_IN = """#!/usr/bin/env bash
shift 2; out=""; resume=0
if [ "$1" = evaluate-ddpg ]; then  # a command without a progress bar: argparse refuses --no-progress
  for a in "$@"; do
    [ "$a" = --no-progress ] && { echo "error: unrecognized arguments: --no-progress" >&2; exit 2; }
  done
  exit 0
fi
for a in "$@"; do [ "$a" = --help ] && { echo "  --no-progress  No progress bar."; exit 0; }; done
for a in "$@"; do [ "$a" = --resume ] && resume=1; done
while [ $# -gt 0 ]; do [ "$1" = --out ] && out=$2; shift; done
if [ $resume = 0 ] && [ -e "$out/chunks" ]; then
  echo "vision-rl train-ddpg: error: $out holds a run: pass --resume to continue it or --force to start over" >&2
  exit 2
fi
n=$(( $(cat "$out/chunks" 2>/dev/null || echo 0) + 1 )); mkdir -p "$out"; echo $n > "$out/chunks"
nice > "$out/niceness"
[ $n -ge 3 ] && exit 0 || exit 124
"""


def _run_lanes(tmp_path: Path, lines: str, **env_vars: str) -> list[str]:
    stand_in = tmp_path / "python"
    stand_in.write_text(STAND_IN)
    stand_in.chmod(0o755)
    lane = tmp_path / "lane.txt"
    lane.write_text(lines)
    env = {**os.environ, "RUNS": str(tmp_path), "PYTHON": str(stand_in), "CODE": str(tmp_path), **env_vars}
    subprocess.run(["bash", str(SCRIPT), "start", str(lane)], env=env, check=True)
    log = tmp_path / "logs" / "lane.log"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        text = log.read_text() if log.is_file() else ""
        if text.count(" rc=0 ") == lines.count("\n") or "FAILED" in text:
            return text.splitlines()
        time.sleep(0.1)
    raise AssertionError(f"the lane did not finish: {log.read_text() if log.is_file() else 'no log'}")


def test_a_line_goes_on_in_chunks_with_resume_once_its_folder_holds_a_run(tmp_path):
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "chunks").write_text("1")  # a run cut short before the machine stopped
    log = _run_lanes(tmp_path, f"train-ddpg --out {tmp_path / 'a'}\ntrain-ddpg --out {tmp_path / 'b'}\n")
    ends = [line.split(" rc=")[1] for line in log if " rc=" in line]
    assert ends == [
        f"124 train-ddpg --out {tmp_path / 'a'} ",  # a fresh run: its first chunk starts it
        f"2 train-ddpg --out {tmp_path / 'a'} ",  # the next is refused without --resume...
        f"124 train-ddpg --out {tmp_path / 'a'} --resume",  # ...and goes on with it
        f"0 train-ddpg --out {tmp_path / 'a'} --resume",
        f"2 train-ddpg --out {tmp_path / 'b'} ",  # a run from before a restart
        f"124 train-ddpg --out {tmp_path / 'b'} --resume",
        f"0 train-ddpg --out {tmp_path / 'b'} --resume",
    ]
    assert (tmp_path / "a" / "chunks").read_text().strip() == "3" and not any("FAILED" in line for line in log)


def test_a_command_without_a_progress_bar_is_not_given_no_progress(tmp_path):
    log = _run_lanes(tmp_path, f"train-ddpg --out {tmp_path / 'a'}\nevaluate-ddpg --agent {tmp_path / 'a'}\n")
    assert log[-1].split(" rc=")[1] == f"0 evaluate-ddpg --agent {tmp_path / 'a'} " and not any(
        "FAILED" in x for x in log
    )


def test_a_lane_runs_at_the_niceness_it_is_given_and_at_the_lowest_priority_by_default(tmp_path):
    base = os.nice(0)
    (tmp_path / "default").mkdir(), (tmp_path / "screen").mkdir()
    _run_lanes(tmp_path / "default", f"train-ddpg --out {tmp_path / 'a'}\n")
    _run_lanes(tmp_path / "screen", f"train-ddpg --out {tmp_path / 'b'}\n", NICE="5")
    assert int((tmp_path / "a" / "niceness").read_text()) == min(base + 19, 19)
    assert int((tmp_path / "b" / "niceness").read_text()) == min(base + 5, 19)
