"""The distribution: a wheel of vision-rl-racing builds from the tree (`python -m build`), its metadata carries the
README as the long description, and installed with --no-deps into a fresh environment (its dependencies from the
test's own environment) it gives `import vision_rl`, `vision-rl --version` and the console scripts."""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
import zipfile
from email.parser import Parser
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DISTRIBUTION = "vision-rl-racing"
SCRIPTS = ("vision-rl", "capture", "train-repr", "train-policy", "bench-latency")


def run(command: list[str], cwd: Path, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=timeout_s)
    assert done.returncode == 0, f"{command}: {done.stdout[-3000:]}{done.stderr[-3000:]}"
    return done


def copy_tree(target: Path) -> Path:
    """The package's sources, as a clone has them (no caches, no run folders), so the build sees no stale state."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc", "*.egg-info", "build", "dist")
    shutil.copytree(ROOT / "vision_rl", target / "vision_rl", ignore=ignore)
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, target / name)
    return target


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_the_wheel_builds_and_installs_under_its_own_name(tmp_path):
    pytest.importorskip("build", reason="the build package is not installed (the dev extra has it)")
    source = copy_tree(tmp_path / "source")
    run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(tmp_path / "dist")], source)
    (wheel,) = (tmp_path / "dist").glob("*.whl")
    assert wheel.name.startswith("vision_rl_racing-")

    with zipfile.ZipFile(wheel) as archive:
        metadata_name = next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))
        metadata = Parser().parsestr(archive.read(metadata_name).decode("utf-8"))
        names = archive.namelist()
    assert metadata["Name"] == DISTRIBUTION
    assert metadata["Description-Content-Type"] == "text/markdown"
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert metadata.get_payload().strip() == readme.strip()
    assert "vision_rl/data/racetrack_database/LICENSE" in names  # the tracks' licence travels with them

    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], tmp_path)
    python = venv / "bin" / "python"
    # A venv made from inside a venv sees the base interpreter's packages, not the outer venv's: a path file hands it
    # the test's own (torch, gymnasium...) after its own site-packages, whose path files (the outer venv's editable
    # vision_rl) are not run, so vision_rl and its metadata come from the wheel.
    inner = run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path)
    outer = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(inner.stdout.strip()) / "outer_site_packages.pth").write_text("\n".join(sorted(outer)) + "\n")
    run([str(python), "-m", "pip", "install", "--no-deps", "--no-index", "--quiet", str(wheel)], tmp_path)
    version = run([str(venv / "bin" / "vision-rl"), "--version"], tmp_path).stdout.strip()
    assert version == f"vision-rl {metadata['Version']}"
    where = run([str(python), "-c", "import vision_rl, sys; print(vision_rl.__file__)"], tmp_path).stdout.strip()
    assert where.startswith(str(venv)), f"vision_rl came from {where}, not from the installed wheel"
    for script in SCRIPTS:
        assert (venv / "bin" / script).is_file(), script
    listing = run([str(venv / "bin" / "capture"), "--help"], tmp_path).stdout
    assert "usage: vision-rl capture" in listing
