"""Killing what a test started: a subprocess with every process it started, and a run's sampler actors."""

from __future__ import annotations

import os
import signal
import subprocess

from vision_rl.training.distributed import ACTOR_PREFIX


def kill_and_read(process: subprocess.Popen) -> str:
    """Kill a test's subprocess and, when it was started with ``start_new_session=True``, every process it started;
    its stderr. A child left running holds the pipes open, and reading them would wait for it for ever."""
    try:
        os.killpg(process.pid, signal.SIGKILL)  # its session's process group
    except ProcessLookupError:  # not a group's leader
        process.kill()
    try:
        return process.communicate(timeout=30)[1]
    except subprocess.TimeoutExpired:
        return "(no output: a process it started holds its pipes open)"


def sampler_killer(ray, at_steps: int, how_many: int):
    """A progress callback that SIGKILLs ``how_many`` of the run's sampler processes once ``at_steps`` is reached."""
    killed: list[int] = []

    def progress(steps: int, total: int, last_eval) -> None:
        if killed or steps < at_steps:
            return
        names = sorted(n for n in ray.util.list_named_actors() if n.startswith(ACTOR_PREFIX))
        for name in names[:how_many]:
            pid = ray.get(ray.get_actor(name).pid.remote())
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    return progress, killed
