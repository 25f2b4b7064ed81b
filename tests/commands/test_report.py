"""`vision-rl report`: the committed README and docs are what their records give (--check passes), a changed record
makes --check fail until the report rewrites the pages, and the table of commands lists every command."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from vision_rl.commands.main import COMMANDS, main
from vision_rl.commands.report import commands_table
from vision_rl.evaluation.report import sealed

ROOT = Path(__file__).resolve().parents[2]


def report(*args: str, root: Path = ROOT) -> int:
    pages = [str(root / "README.md"), str(root / "docs")]
    return main(["report", "--pages", *pages, "--results", str(root / "docs" / "results"), *args])


def test_the_committed_pages_are_up_to_date(capsys):
    assert report("--check", "--json") == 0, capsys.readouterr().out
    states = json.loads(capsys.readouterr().out)
    assert states[str(ROOT / "README.md")] == "up to date"
    assert any("docs/papers" in page for page in states)  # the papers' pages hold tables too
    assert all(state == "up to date" for state in states.values())


def test_a_changed_record_makes_the_pages_stale_until_the_report_runs(tmp_path, capsys):
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    shutil.copytree(ROOT / "docs", tmp_path / "docs", ignore=shutil.ignore_patterns("*.png", "*.mp4", "*.csv"))
    assert report(root=tmp_path) == 0  # the copy as its records and this tree's commands give it
    capsys.readouterr()
    job = tmp_path / "docs" / "results" / "make-quick" / "job.json"
    record = json.loads(job.read_text(encoding="utf-8"))
    record["job_minutes"] = 9.4
    job.write_text(json.dumps(sealed(record)), encoding="utf-8")  # a record measured again, sealed as written

    assert report("--check", root=tmp_path) == 1
    assert f"{tmp_path / 'README.md'}: stale" in capsys.readouterr().out
    readme_before = (tmp_path / "README.md").read_text(encoding="utf-8")
    assert report(root=tmp_path) == 0
    assert f"{tmp_path / 'README.md'}: rewritten" in capsys.readouterr().out
    readme = (tmp_path / "README.md").read_text(encoding="utf-8")
    assert "| 9.4 min (" in readme and "| 9.4 min (" not in readme_before
    assert readme.replace("9.4 min", "10.6 min") == readme_before  # nothing else on the page moved
    assert report("--check", root=tmp_path) == 0


def test_a_page_naming_an_unknown_table_is_refused(tmp_path, capsys):
    page = tmp_path / "page.md"
    page.write_text("<!-- report:nonesuch -->\n<!-- /report -->\n", encoding="utf-8")
    results = str(ROOT / "docs" / "results")
    assert main(["report", "--pages", str(page), "--results", results]) == 2
    assert "no table called 'nonesuch'" in capsys.readouterr().err
    assert main(["report", "--pages", str(tmp_path / "absent.md"), "--results", results]) == 2


def test_the_commands_table_lists_every_command_and_the_console_scripts():
    table = commands_table()
    assert all(f"`vision-rl {name}`" in table for name in COMMANDS)
    assert "`vision-rl capture` (or `capture`)" in table and "`vision-rl report`" in table
    assert len(table.splitlines()) == len(COMMANDS) + 2
