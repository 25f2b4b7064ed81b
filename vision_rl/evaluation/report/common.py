"""What every paper's tables share: laps and gaps as the papers write them, Markdown rows and links to the records,
and the built-in AI's lap and the physical limit of each paper's track and car (and their table)."""

from __future__ import annotations

import statistics
from collections.abc import Iterable

from vision_rl.evaluation.report.records import RESULTS, Records, ReportError

AI_HATCHBACK = "reference-laps/ai_expressway_hatchback.json"
AI_TT_CUP = "reference-laps/ai_expressway_tt_cup.json"
AI_GT3 = "reference-laps/ai_catalunya_gt3.json"


def lap_text(seconds: float | None, decimals: int = 3) -> str:
    """A lap as the papers write it: ``2:09.293`` (``2:09.29`` to 2 ``decimals``); ``DNF`` for none."""
    if seconds is None:
        return "DNF"
    minutes, rest_s = divmod(round(seconds * 10**decimals) / 10**decimals, 60.0)
    return f"{int(minutes)}:{rest_s:0{3 + decimals}.{decimals}f}" if minutes else f"{rest_s:.{decimals}f} s"


def gap_pct(seconds: float, reference_s: float) -> float:
    """How much longer ``seconds`` is than ``reference_s``, in percent (negative: faster)."""
    return 100.0 * (seconds / reference_s - 1.0)


def gap_text(seconds: float, reference_s: float) -> str:
    return f"{gap_pct(seconds, reference_s):+.2f} %"


def faster_text(seconds: float, ai_s: float) -> str:
    """``7.18 % faster than the AI`` (or slower)."""
    gap = gap_pct(seconds, ai_s)
    return f"{abs(gap):.2f} % {'faster' if gap < 0 else 'slower'} than the AI"


def mean_std_s(laps_s: Iterable[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value) of lap times, s."""
    laps_s = list(laps_s)
    if not laps_s:
        raise ReportError("no lap to average")
    return statistics.fmean(laps_s), statistics.stdev(laps_s) if len(laps_s) > 1 else 0.0


def _row(cells: Iterable[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def markdown_table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> str:
    header = list(header)
    lines = [_row(header), _row("---" for _ in header), *(_row(row) for row in rows)]
    return "\n".join(lines) + "\n"


def bold_if(text: str, bold: bool) -> str:
    """``text`` in bold where its row is the one its section is about."""
    return f"**{text}**" if bold else text


def link(text: str, relative_path: str) -> str:
    return f"[{text}]({RESULTS}{relative_path})"


def reference_laps(records: Records, path: str) -> tuple[float, float]:
    """The built-in AI's protocol lap and the physical limit (QSS) of a track and car, s."""
    ai = records(path)
    return ai["best_lap_time_s"], ai["limit_lap_time_s"]


def span_text(values: Iterable[float], unit: str, spec: str = ".0f") -> str:
    """The range of ``values`` written with the format ``spec``, ``a-b unit``, or ``a unit`` when they read alike."""
    values = list(values)
    low, high = (f"{x:{spec}}" for x in (min(values), max(values)))
    return f"{low} {unit}" if low == high else f"{low}-{high} {unit}"


def span_m(distances_m: Iterable[float]) -> str:
    """The range of distances in whole metres, ``a-b m``, or ``a m`` when they round alike."""
    return span_text(distances_m, "m", ",.0f")


def reference_table(records: Records) -> str:
    """The built-in AI's protocol lap and the physical limit of each track and car the papers' tables use, and the
    straight driver's (full throttle, never steering): the floor a learned driver must beat."""
    rows = []
    for path, pair in (
        (AI_HATCHBACK, "expressway, hatchback"),
        (AI_TT_CUP, "expressway, tt_cup"),
        (AI_GT3, "Catalunya, gt3"),
    ):
        ai_s, limit_s = reference_laps(records, path)
        ai = (
            f"{lap_text(ai_s)} (skill {records(path)['driver']['skill']})",
            lap_text(limit_s),
            gap_text(ai_s, limit_s),
        )
        straight_path = path.replace("/ai_", "/straight_")
        straight = records(straight_path)
        lap_s, best = straight["best_lap_time_s"], straight["best_lap"]
        straight_lap = "DNF" if lap_s is None else f"{lap_text(lap_s)} ({best['wall_contact_s']:.0f} s on the walls)"
        rows.append(
            (
                pair,
                *ai,
                f"{straight_lap}, {straight['n_finished']} of {straight['n_seeds']} starts",
                f"{link('record', path)}, {link('record', straight_path)}",
            )
        )
    header = ("track, car", "built-in AI", "physical limit", "the AI above the limit", "straight driver", "records")
    return markdown_table(header, rows)


def steps_text(steps: int) -> str:
    """``400k``, ``1.2M``, ``2M``."""
    return f"{steps / 1e6:g}M" if steps >= 1_000_000 else f"{steps / 1e3:g}k"
