"""The front door: the README is a front page (at most 200 lines, contents on its first screen, install and a quick
start within its first 60 lines, no dated figures, links that resolve), and the docs site builds with every warning,
broken links included, as an error (`mkdocs build --strict`)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: A relative Markdown link's target: ``[text](path)`` or ``[text](path#anchor)``, not a URL or an anchor alone.
LINK = re.compile(r"\]\((?!https?://|#|mailto:)([^)#\s]+)(?:#[^)]*)?\)")


def heading_line(lines: list[str], heading: str) -> int:
    """1-based line number of a README heading."""
    return next(number for number, line in enumerate(lines, 1) if line.strip() == heading)


def test_the_readme_is_a_front_page():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines; the front page holds at most 200"
    assert any(line.startswith("**Contents**") for line in lines[:25]), "no contents list on the first screen"
    assert heading_line(lines, "## Install") <= 60 and heading_line(lines, "## Quick start") <= 60
    quick_start = "\n".join(lines[heading_line(lines, "## Quick start") :])
    assert 'gym.make("vision_rl/TimeTrial-v2"' in quick_start and "vision_rl.evaluate(" in quick_start
    for heading in ("## The two commands", "## Results", "## Commands", "## Citation", "## Licence"):
        heading_line(lines, heading)  # each section is there
    dated = [line for line in lines if re.search(r"\b20\d\d-\d\d-\d\d\b", line)]
    assert not dated, f"dated lines on the front page: {dated}"


def test_the_readme_links_resolve_and_cite_the_three_papers():
    text = README.read_text(encoding="utf-8")
    missing = [target for target in LINK.findall(text) if not (ROOT / target).exists()]
    assert not missing, f"README.md links to missing files: {missing}"
    for arxiv in ("2111.06449", "2103.14666"):
        assert f"eprint = {{{arxiv}}}" in text.replace("  ", " ") or f"{{{arxiv}}}" in text
    assert text.count("@inproceedings{") + text.count("@misc{") == 3
    for name in ("LICENSE", "CITATION.cff"):
        assert (ROOT / name).is_file(), name
    assert "MIT License" in (ROOT / "LICENSE").read_text(encoding="utf-8")


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_docs_site_builds_strictly(tmp_path):
    pytest.importorskip("mkdocs", reason="the docs extra is not installed: pip install -e '.[docs]'")
    pytest.importorskip("material", reason="mkdocs-material is not installed: pip install -e '.[docs]'")
    pytest.importorskip("mkdocstrings_handlers.python", reason="mkdocstrings[python] is not installed")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=170,
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    site = tmp_path / "site"
    for page in ("index.html", "papers/vision/index.html", "reference/sim/index.html", "studies/index.html"):
        assert (site / page).is_file(), page
    vision = (site / "papers/vision/index.html").read_text(encoding="utf-8")
    assert "2:09.293" in vision  # the generated table made it onto the page
