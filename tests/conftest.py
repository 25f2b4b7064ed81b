"""Fixtures of every test: a private cache and working folder, and the guard of the tests that render."""

from __future__ import annotations

import os
import signal
import subprocess

import pytest


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


def renderer_available() -> str:
    """Empty if a headless EGL context can be made here, else the reason."""
    try:
        from vision_rl.render import create_context

        create_context().release()
        return ""
    except Exception as exc:  # no EGL library, no driver, no moderngl
        return f"vision_rl.render cannot make an EGL context here: {exc}"


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
