"""The front door: the README is a front page (at most 200 lines, contents on its first screen, install and a quick
start within its first 60 lines, no dated figures, links that resolve), every `vision-rl` command the README and the
docs show exists with the options it is shown with, and the docs site builds with every warning, broken links
included, as an error (`mkdocs build --strict`)."""

from __future__ import annotations

import argparse
import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from vision_rl.commands.main import COMMANDS
from vision_rl.commands.options import add_config_arguments

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: A relative Markdown link's target: ``[text](path)`` or ``[text](path#anchor)``, not a URL or an anchor alone.
LINK = re.compile(r"\]\((?!https?://|#|mailto:)([^)#\s]+)(?:#[^)]*)?\)")


FENCE = re.compile(r"^\s*```")
INLINE_COMMAND = re.compile(r"`(vision-rl [^`]+)`")
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
#: Where a shown command names no real one: a placeholder (``vision-rl COMMAND``) or the program's own flags.
PLACEHOLDER = re.compile(r"[A-Z_.|-]+|--version|--help|-h")


def shown_commands(text: str) -> list[tuple[int, str]]:
    """(line, command) for each ``vision-rl ...`` of a Markdown text: a line of a fenced block (its ``\\``
    continuations joined) or an inline code span; a trailing ``# comment`` is cut."""
    lines, inside, found, i = text.split("\n"), False, [], 0
    while i < len(lines):
        line = lines[i]
        if FENCE.match(line):
            inside = not inside
        elif inside and line.strip().removeprefix("$ ").startswith("vision-rl "):
            start, command = i + 1, line.strip().removeprefix("$ ")
            while command.rstrip().endswith("\\") and i + 1 < len(lines):
                i += 1
                command = command.rstrip()[:-1] + " " + lines[i].strip()
            found.append((start, command))
        elif not inside:
            found += [(i + 1, m.group(1)) for m in INLINE_COMMAND.finditer(line)]
        i += 1
    return [(n, command.split(" # ")[0]) for n, command in found]


def _flags(name: str) -> set[str]:
    command = COMMANDS[name]
    parser = argparse.ArgumentParser(prog=f"vision-rl {name}")
    add_config_arguments(parser, getattr(importlib.import_module(command.module), command.options))
    return {flag for action in parser._actions for flag in action.option_strings}


def command_problems(text: str, where: str) -> list[str]:
    """A line per shown command that does not exist, or shown with an option its parser does not have (argparse
    would take an abbreviation for another option, or refuse it)."""
    problems = []
    for n, command in shown_commands(text):
        tokens = command.split()
        name = " ".join(tokens[1:3]) if " ".join(tokens[1:3]) in COMMANDS else tokens[1] if len(tokens) > 1 else ""
        if name not in COMMANDS:
            if not PLACEHOLDER.fullmatch(name):
                problems.append(f"{where}:{n}: no command {name!r}")
            continue
        unknown = sorted(set(FLAG.findall(command)) - _flags(name))
        if unknown:
            problems.append(f"{where}:{n}: vision-rl {name} has no {', '.join(unknown)}")
    return problems


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


def test_no_docs_page_is_dated():
    """The docs speak of the project (commits, occasions, the machine), not of when someone measured (the README's
    own check is the front page's)."""
    dated = [
        f"{page.relative_to(ROOT)}:{n}"
        for page in sorted((ROOT / "docs").rglob("*.md"))
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1)
        if re.search(r"\b20\d\d-\d\d-\d\d\b|\b(?:that evening|at night|this morning|today's)\b", line)
    ]
    assert not dated, f"dated lines: {dated}"


def test_the_command_check_finds_a_missing_command_and_option():
    text = "```bash\nvision-rl experiment --steps 10 \\\n    --seeds 0,1,2   # a comment --nothing\n```\n"
    text += "Then `vision-rl no-such --x` and `vision-rl COMMAND --help`, and `vision-rl bench sim --json`.\n"
    assert command_problems(text, "t.md") == [
        "t.md:2: vision-rl experiment has no --seeds",
        "t.md:5: no command 'no-such'",
    ]


def test_every_command_the_docs_show_exists_with_its_options():
    pages = [README, *sorted((ROOT / "docs").rglob("*.md"))]
    problems = [
        p for page in pages for p in command_problems(page.read_text(encoding="utf-8"), str(page.relative_to(ROOT)))
    ]
    assert not problems, "\n".join(problems)


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
