"""`vision-rl report`: the README's and the docs' result tables regenerated from the records under docs/results/
(:mod:`vision_rl.evaluation.report`), and the table of every command from the dispatcher's own list; ``--check``
writes nothing and fails when a page's table is not what its records give."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vision_rl.commands.output import emit


@dataclass(frozen=True)
class ReportOptions:
    """Regenerate the tables between <!-- report:NAME --> and <!-- /report --> on the pages from the JSON records."""

    pages: tuple[str, ...] = ("README.md", "docs")
    """Pages to fill: Markdown files, or folders searched for them (the results folders' own pages too)."""
    results: str = "docs/results"
    """The records' folder."""
    check: bool = False
    """Write nothing; exit 1 when a page's tables differ from what the records give."""
    json: bool = False
    """Print the pages and their state as JSON."""


def commands_table() -> str:
    """Every command of ``vision-rl`` with its one-line help, and the console scripts that alias some of them."""
    from vision_rl.commands.main import COMMANDS
    from vision_rl.evaluation.report import markdown_table

    aliases = ("capture", "train-repr", "train-policy", "bench-latency")
    rows = [
        (f"`vision-rl {name}`" + (f" (or `{name}`)" if name in aliases else ""), command.help.replace("|", "/"))
        for name, command in COMMANDS.items()
    ]
    return markdown_table(("command", "what it does"), rows)


def _pages(options: ReportOptions) -> list[Path]:
    found: list[Path] = []
    for entry in map(Path, options.pages):
        if entry.is_dir():
            found += sorted(entry.rglob("*.md"))
        elif entry.is_file():
            found.append(entry)
        else:
            raise ValueError(f"--pages: {entry} is neither a Markdown file nor a folder")
    return found


def run_report(opts: ReportOptions) -> int:
    from vision_rl.evaluation.report import ReportError, render_pages
    from vision_rl.files import atomic_write

    if not Path(opts.results).is_dir():
        raise ValueError(f"--results: no folder {opts.results}")
    try:
        rendered = render_pages(_pages(opts), opts.results, {"commands": commands_table()})
    except ReportError as exc:
        raise ValueError(str(exc)) from exc
    stale = [page for page, (now, new) in rendered.items() if now != new]
    if not opts.check:
        for page in stale:
            new_text = rendered[page][1]
            atomic_write(page, lambda tmp, text=new_text: tmp.write_text(text, encoding="utf-8"))
    state = "stale" if opts.check else "rewritten"
    result = {str(page): (state if page in stale else "up to date") for page in rendered}
    emit(result, opts.json)
    return 1 if opts.check and stale else 0
