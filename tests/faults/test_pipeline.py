"""The pipeline stopped while its two policies train side by side."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.helpers.processes import kill_and_read
from tests.helpers.rendering import renderer_available

_SCRIPT = """
import dataclasses, sys
from vision_rl.commands.output import interrupt_on_sigterm
from vision_rl.commands.pipeline import SIZES, pipeline_phase2
interrupt_on_sigterm()
sizes = dataclasses.replace(SIZES["tiny"], state_steps=1_000_000, vision_steps=1_000_000)
try:
    pipeline_phase2(sys.argv[1], sizes, mode="tiny", track=sys.argv[2], runs=sys.argv[3], device="cpu")
except KeyboardInterrupt:
    raise SystemExit(130)
"""


def _children(pid: int) -> set[int]:
    found = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout.split()
    return {int(p) for p in found}


def _niceness(pid: int) -> int | None:
    try:
        return int(open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[16])
    except (OSError, IndexError, ValueError):  # ended meanwhile
        return None


def test_a_stopped_pipeline_leaves_no_policy_training_alone(small_track, tiny_encoders, tmp_path, fault):
    reason = renderer_available()
    if reason:
        pytest.skip(reason)
    runs = tmp_path / "runs"
    process = subprocess.Popen(
        [sys.executable, "-c", _SCRIPT, str(tiny_encoders[0]), small_track, str(runs)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    # The vision policy trains (its first evaluation is written) and the state policy's process runs at the lowest
    # priority: on a busy machine that process may take minutes to get as far, so the test does not wait for it.
    lowest = min(19, os.nice(0) + 19)
    deadline = time.monotonic() + 240
    while True:
        children = {pid for pid in _children(process.pid) if _niceness(pid) == lowest}
        if children and (runs / "policy" / "pipeline-vision" / "metrics.jsonl").exists():
            break
        if process.poll() is not None or time.monotonic() > deadline:
            stderr = kill_and_read(process)
            raise AssertionError(f"no vision training beside a state process at nice {lowest}: {stderr}")
        time.sleep(0.1)
    os.kill(process.pid, signal.SIGTERM)
    try:
        _, stderr = process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the pipeline did not stop within 60 s of SIGTERM: {kill_and_read(process)}") from None
    assert process.returncode == 130, stderr
    time.sleep(0.5)
    alive = {
        pid for pid in children if os.path.exists(f"/proc/{pid}") and "zombie" not in open(f"/proc/{pid}/status").read()
    }
    assert not alive, f"left running: {alive}"
    fault.recovered(
        "SIGTERM to pipeline while state and vision policies train",
        "both stop (the state policy's process with the pipeline), exit 130; capture and encoder are kept",
    )
