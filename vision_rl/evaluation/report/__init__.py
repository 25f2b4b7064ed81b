"""The result tables of the README and of the docs site, built from the JSON records under docs/results/.

A page marks a table's place with ``<!-- report:NAME -->`` and ``<!-- /report -->``; :func:`fill_page` writes between
them the table that :data:`TABLES` builds from the records, so every figure such a table states is its record's, and
a changed record leaves the page stale until ``vision-rl report`` runs again (``--check`` fails on a stale page).
A table links its records as ``RESULTS/...``, resolved against each page's own folder.

The papers' own figures are records too (``docs/results/papers/``), the built-in AI's lap and the physical limit come
from the protocol's evaluations of the AI (``docs/results/reference-laps/``), and the figures that exist only as a
command's printed summary are transcribed into a record that says so (``make-quick/job.json``,
``phase1-expressway-hatchback/r2.json``).

``records`` reads and seals the records, ``common`` writes laps, gaps and Markdown, one module per paper (and
``state`` and ``scaling`` for those studies) builds its tables, and ``pages`` names them all and fills the pages.
"""

from vision_rl.evaluation.report.common import (
    AI_HATCHBACK,
    AI_TT_CUP,
    gap_text,
    lap_text,
    markdown_table,
    mean_std_s,
)
from vision_rl.evaluation.report.overtaking import CURRICULUM_CURVES, SETTINGS, TABLE3
from vision_rl.evaluation.report.pages import (
    TABLES,
    build_tables,
    fill_page,
    marked_tables,
    page_results_href,
    records_read,
    render_pages,
)
from vision_rl.evaluation.report.records import (
    RESULTS,
    Records,
    ReportError,
    record_damage,
    seal_record_file,
    sealed,
)
from vision_rl.evaluation.report.vision import QUICK_JOB

__all__ = [
    "AI_HATCHBACK",
    "AI_TT_CUP",
    "CURRICULUM_CURVES",
    "QUICK_JOB",
    "RESULTS",
    "SETTINGS",
    "TABLE3",
    "TABLES",
    "Records",
    "ReportError",
    "build_tables",
    "fill_page",
    "gap_text",
    "lap_text",
    "markdown_table",
    "marked_tables",
    "mean_std_s",
    "page_results_href",
    "record_damage",
    "records_read",
    "render_pages",
    "seal_record_file",
    "sealed",
]
