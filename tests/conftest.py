"""Fixtures of more than one test folder: a private cache and working folder, the guard of the tests that render,
the local Ray cluster, and a small track with tiny encoders, a tiny trained policy and recorded demonstrations.
A folder's own fixtures stay in its conftest; the helpers they share are in tests/helpers."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.helpers.policies import tiny_train_config, write_tiny_encoder
from tests.helpers.rendering import renderer_available
from tests.helpers.tracks import STADIUM, stadium_csv


@pytest.fixture(scope="session", autouse=True)
def _private_cache_and_runs(tmp_path_factory):
    """Racing lines, profiles and statistics go to a temporary ``VISION_RL_CACHE``, Stable-Baselines3's default log
    folder of a model that learns without a logger set (``tempdir/SB3-<date>`` otherwise, one per test left behind)
    to a temporary ``SB3_LOGDIR``, and relative run folders (the commands' default ``runs/...``) to a temporary
    working folder: no test writes to ``~/.cache``, the system's temporary folder or the checkout.

    Session-wide (not monkeypatch) because session-scoped fixtures, such as a trained policy, need it too."""
    old_env = {name: os.environ.get(name) for name in ("VISION_RL_CACHE", "SB3_LOGDIR")}
    old_cwd = os.getcwd()
    os.environ["VISION_RL_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))
    os.chdir(tmp_path_factory.mktemp("work"))
    try:
        yield
    finally:
        os.chdir(old_cwd)
        for name, value in old_env.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@pytest.fixture(scope="session")
def gl_available() -> None:
    """Skip (with the reason) when this machine has no EGL/OpenGL: the renderer cannot run here at all."""
    reason = renderer_available()
    if reason:
        pytest.skip(reason)


def pytest_configure(config):
    if config.getoption("--fault-table") and getattr(config.option, "numprocesses", None):
        # Each worker process would write its own share of the outcomes over the others'.
        raise pytest.UsageError("--fault-table collects the outcomes in one process: run it without -n (make faults)")


def pytest_collection_modifyitems(config, items):
    """Under ``pytest -n`` (``make test``), every test on the shared local Ray cluster goes to one worker process
    (``--dist loadgroup``): one cluster, started once, and never two of them on the same cores."""
    for item in items:
        if "ray_local" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("ray"))


def pytest_addoption(parser):
    parser.addoption(
        "--fault-table",
        default="",
        help="write the fault suite's outcomes (tests/faults) as a Markdown table to this path (make faults)",
    )


@pytest.fixture(scope="session")
def ray_local():
    """A local Ray cluster of 2 CPUs shared by every test that needs one (starting one costs about 5 s); skipped
    with the reason only when Ray is not installed (the dev extra installs it)."""
    ray = pytest.importorskip("ray", reason="Ray is not installed: pip install 'vision_rl[ray]'")
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        yield ray
    finally:
        ray.shutdown()


@pytest.fixture(scope="session")
def small_track(tmp_path_factory) -> str:
    """The 677 m stadium (``STADIUM``) as a CSV path."""
    return str(stadium_csv(tmp_path_factory.mktemp("track") / "stadium.csv", *STADIUM))


@pytest.fixture(scope="session")
def tiny_encoders(tmp_path_factory) -> tuple[Path, Path]:
    """Two encoder checkpoints of one architecture with different weights (so different SHA-256)."""
    root = tmp_path_factory.mktemp("encoders")
    return write_tiny_encoder(root / "a" / "ckpt.pt", 0), write_tiny_encoder(root / "b" / "ckpt.pt", 1)


@pytest.fixture(scope="session")
def state_run(tmp_path_factory, small_track) -> tuple[Path, dict]:
    """A state policy trained for 200 steps (2 cars) on the small track: (run folder, train_policy result)."""
    from vision_rl.phase2_rl.train import train_policy

    out = tmp_path_factory.mktemp("runs") / "policy" / "tiny-state"
    return out, train_policy(tiny_train_config(small_track, out))


@pytest.fixture(scope="session")
def small_demos(tmp_path_factory, small_track):
    """Two laps of demonstrations on the small track: 2 cars, 20 s episodes (so several episodes per car)."""
    from tests.helpers.overtaking import DEMOS_CAR
    from vision_rl.overtaking.config import RecordDemosConfig
    from vision_rl.overtaking.demos import record_demos

    out = tmp_path_factory.mktemp("demos") / "ai.npz"
    result = record_demos(
        RecordDemosConfig(track=small_track, car=DEMOS_CAR, laps=2.0, cars=2, episode_s=20.0, seed=3, out=str(out))
    )
    return out, result
