"""The pipeline stopped while its two policies train side by side."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.conftest import renderer_available

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


def test_a_stopped_pipeline_leaves_no_policy_training_alone(small_track, tiny_encoders, tmp_path, fault):
    reason = renderer_available()
    if reason:
        pytest.skip(reason)
    runs = tmp_path / "runs"
    process = subprocess.Popen([sys.executable, "-c", _SCRIPT, str(tiny_encoders[0]), small_track, str(runs)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    deadline = time.monotonic() + 120
    folders = [runs / "policy" / f"pipeline-{kind}" / "metrics.jsonl" for kind in ("state", "vision")]
    while not all(f.exists() for f in folders):  # both policies train (their first evaluations are written)
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            raise AssertionError(f"the policies did not both start training: {process.communicate()}")
        time.sleep(0.1)
    children = _children(process.pid)
    assert children, "the state policy trains in a second process"
    niceness = [int(open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[16]) for pid in children]
    assert min(19, os.nice(0) + 19) in niceness, "the state policy trains at the lowest priority"
    os.kill(process.pid, signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    time.sleep(0.5)
    alive = {pid for pid in children if os.path.exists(f"/proc/{pid}") and "zombie" not in
             open(f"/proc/{pid}/status").read()}  # fmt: skip
    assert not alive, f"left running: {alive}"
    fault.recovered("SIGTERM to pipeline while state and vision policies train",
                    "both stop (the state policy's process with the pool), exit 130; capture and encoder are kept")
