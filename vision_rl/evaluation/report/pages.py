"""The pages: :data:`TABLES` names every table a page can mark, :func:`render_pages` fills the marked places."""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterable, Mapping
from functools import partial
from pathlib import Path

from vision_rl.evaluation.report.common import reference_table
from vision_rl.evaluation.report.ddpg import (
    DDPG_STATE_ACTOR_SCREENS,
    ddpg_bench_table,
    ddpg_equal_compute_table,
    ddpg_first_trainings_table,
    ddpg_reference_table,
    ddpg_state_actor_table,
    ddpg_table,
)
from vision_rl.evaluation.report.overtaking import (
    DREAMER_MODEL_INTERIM,
    SETTINGS,
    TABLE3_DREAMER_INTERIM,
    TABLE3_FIRST,
    bc_recipes_table,
    dreamer_model_table,
    fig3_reach_table,
    opponent_skill_table,
    overtaking_seeds_table,
    overtaking_table,
    settings_drivers_table,
    table3_runs_table,
    table3_summary_table,
)
from vision_rl.evaluation.report.records import RESULTS, Records, ReportError
from vision_rl.evaluation.report.scaling import SCALING_TABLES
from vision_rl.evaluation.report.state import STATE_TABLES
from vision_rl.evaluation.report.vision import phase1_table, quick_table, vision_table
from vision_rl.evaluation.report.vision_agent import VISION_AGENT_TABLES
from vision_rl.evaluation.report.vision_log import VISION_LOG_TABLES

#: A generated table's place on a page: the opening marker names the table, the closing one ends it.
MARKER = re.compile(r"(?P<open><!-- report:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(?P<close><!-- /report -->)", re.S)

#: Every table a page can name in a marker, built from the records.
TABLES: dict[str, Callable[[Records], str]] = {
    "reference": reference_table,
    "vision": vision_table,
    "quick": quick_table,
    "phase1": phase1_table,
    "overtaking": overtaking_table,
    "opponent-skill": opponent_skill_table,
    "overtaking-settings": partial(
        settings_drivers_table,
        paths=[SETTINGS.format(agents=a, setting=x) for x in ("A", "B") for a in ("agent1", "agents23")],
    ),
    "c-r-ablation": partial(
        settings_drivers_table,
        paths=[f"overtaking-expressway-tt_cup/c_r_ablation/setting_{x}.json" for x in ("A", "B")],
    ),
    "table3-summary": table3_summary_table,
    "table3-runs": table3_runs_table,
    "table3-first-runs": partial(table3_runs_table, paths=(TABLE3_FIRST,)),
    "table3-dreamer-interim": partial(table3_runs_table, paths=(TABLE3_DREAMER_INTERIM,)),
    "dreamer-model-interim": partial(dreamer_model_table, paths=DREAMER_MODEL_INTERIM),
    "dreamer-model": dreamer_model_table,
    "fig3-reach": fig3_reach_table,
    "bc-recipes": bc_recipes_table,
    "overtaking-seeds": overtaking_seeds_table,
    "ddpg": ddpg_table,
    "ddpg-first-trainings": ddpg_first_trainings_table,
    "ddpg-reference-pendulum": partial(ddpg_reference_table, task="Pendulum-v1"),
    "ddpg-reference-mountaincar": partial(
        ddpg_reference_table, task="MountainCarContinuous-v0", decimals=1, time_limit_steps=999
    ),
    "ddpg-bench": ddpg_bench_table,
    "ddpg-equal-compute": ddpg_equal_compute_table,
    **{name: partial(ddpg_state_actor_table, name=name) for name in DDPG_STATE_ACTOR_SCREENS},
    **STATE_TABLES,
    **SCALING_TABLES,
    **VISION_LOG_TABLES,
    **VISION_AGENT_TABLES,
}


def build_tables(results_dir: str | os.PathLike[str], names: Iterable[str] | None = None) -> dict[str, str]:
    """The tables named (all of :data:`TABLES` by default) from the records under ``results_dir``."""
    records = Records(results_dir)
    tables = {}
    for name in TABLES if names is None else names:
        try:
            tables[name] = TABLES[name](records)
        except ReportError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, ArithmeticError) as exc:
            # A record of another shape than the table's (edited, damaged or of an older writer).
            raise ReportError(
                f"the {name} table cannot read its records (the last read: {records.last}): {type(exc).__name__} {exc}"
            ) from None
    return tables


def records_read(results_dir: str | os.PathLike[str]) -> list[Path]:
    """Every record the tables of :data:`TABLES` read under ``results_dir``, their seals not checked: what
    ``scripts/seal_records.py`` seals when named no file."""
    records = Records(results_dir, check=False)
    for table in TABLES.values():
        table(records)
    return sorted(records.results_dir / relative for relative in records._read)


def marked_tables(text: str) -> list[str]:
    """The names of the tables a page marks, in order; :class:`ReportError` on a marker without its end."""
    names = [m.group("name") for m in MARKER.finditer(text)]
    if text.count("<!-- report:") != len(names) or text.count("<!-- /report -->") != len(names):
        raise ReportError("a <!-- report:NAME --> marker without its <!-- /report --> (or the other way round)")
    return names


def fill_page(text: str, tables: Mapping[str, str], results_href: str) -> str:
    """``text`` with every marked table replaced by ``tables[name]``, its record links made relative to the page
    (``results_href``: the page's path to the results folder)."""
    marked_tables(text)
    href = results_href.rstrip("/") + "/"

    def table(match: re.Match) -> str:
        name = match.group("name")
        if name not in tables:
            raise ReportError(f"no table called {name!r}; known: {', '.join(sorted(tables))}")
        body = tables[name].replace(RESULTS, href)
        return f"{match.group('open')}{body}{match.group('close')}"

    return MARKER.sub(table, text)


def page_results_href(page: str | os.PathLike[str], results_dir: str | os.PathLike[str]) -> str:
    """The relative path from ``page``'s folder to ``results_dir``, with forward slashes."""
    return Path(os.path.relpath(Path(results_dir).resolve(), Path(page).resolve().parent)).as_posix()


def render_pages(
    pages: Iterable[str | os.PathLike[str]],
    results_dir: str | os.PathLike[str],
    extra_tables: Mapping[str, str] | None = None,
) -> dict[Path, tuple[str, str]]:
    """``{page: (text now, text with its tables regenerated)}`` for each page that marks a table."""
    texts = {Path(p): Path(p).read_text(encoding="utf-8") for p in pages}
    marked = {page: text for page, text in texts.items() if marked_tables(text)}
    wanted = {name for text in marked.values() for name in marked_tables(text)} - set(extra_tables or {})
    tables = {**build_tables(results_dir, sorted(wanted & set(TABLES))), **(extra_tables or {})}
    return {
        page: (text, fill_page(text, tables, page_results_href(page, results_dir))) for page, text in marked.items()
    }
