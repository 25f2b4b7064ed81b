"""Where a lap is won or lost: a recorded protocol lap cut into sections of the track, and two laps compared
section by section.

A section's time is the time from the car first reaching its start (centre-line progress within the scored lap)
to first reaching its end; the sections' times add up to the lap time. Its minimum speed and wall contact come from
the protocol's 0.1 s records whose progress lies in it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vision_rl.evaluation.protocol import STEP_S, LapTiming


def lap_sections(timing: LapTiming, index: int, section_m: float) -> dict[str, np.ndarray]:
    """Sections of ``section_m`` (the last one shorter) of run ``index``'s scored lap of a ``record=True`` timing:
    ``start_m``, ``time_s``, ``min_speed_kmh`` (nan where no record fell), ``wall_contact_s``."""
    if section_m <= 0:
        raise ValueError(f"section_m must be > 0, got {section_m}")
    if timing.time_s.size == 0:
        raise ValueError("the timing holds no records: run the protocol with record=True")
    if timing.scored(index) is None:
        raise ValueError(f"run {index} did not finish its scored lap: {timing.runs[index].dnf_reason}")
    track = timing.track
    length_m = track.length_m
    t0, t1 = timing.scored_window_s(index)
    inside = (timing.time_s > t0) & (timing.time_s < t1)
    t = timing.time_s[inside]
    s = track.project(np.column_stack([timing.x_m[inside, index], timing.y_m[inside, index]])).s_m
    # Progress since the lap line, unwrapped; the furthest point reached so far is what a section's time counts.
    steps = (np.diff(s) + 0.5 * length_m) % length_m - 0.5 * length_m
    progress = np.concatenate([[s[0] if s[0] < 0.5 * length_m else s[0] - length_m], np.zeros(len(steps))])
    progress[1:] = progress[0] + np.cumsum(steps)
    reached = np.clip(np.maximum.accumulate(progress), 0.0, length_m)
    edges = np.append(np.arange(0.0, length_m, section_m), length_m)
    at_edge_s = np.interp(edges, np.concatenate([[0.0], reached, [length_m]]), np.concatenate([[t0], t, [t1]]))
    n = len(edges) - 1
    which = np.minimum((np.clip(progress, 0.0, length_m - 1e-9) // section_m).astype(np.int64), n - 1)
    min_speed = np.full(n, np.inf)
    np.minimum.at(min_speed, which, timing.speed_mps[inside, index] * 3.6)
    wall = np.zeros(n)
    np.add.at(wall, which, timing.wall_contact[inside, index] * STEP_S)
    return {
        "start_m": edges[:-1],
        "time_s": np.diff(at_edge_s),
        "min_speed_kmh": np.where(np.isfinite(min_speed), min_speed, np.nan),
        "wall_contact_s": wall,
    }


def compare_sections(lap: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """Per section, a lap against a reference lap of the same sections: JSON-ready rows with ``loss_s`` (positive:
    the lap is slower there)."""
    if not np.array_equal(lap["start_m"], reference["start_m"]):
        raise ValueError("the laps are cut into different sections")
    return [
        {
            "start_m": float(lap["start_m"][j]),
            "time_s": float(lap["time_s"][j]),
            "reference_time_s": float(reference["time_s"][j]),
            "loss_s": float(lap["time_s"][j] - reference["time_s"][j]),
            "min_speed_kmh": float(lap["min_speed_kmh"][j]),
            "reference_min_speed_kmh": float(reference["min_speed_kmh"][j]),
            "wall_contact_s": float(lap["wall_contact_s"][j]),
        }
        for j in range(len(lap["start_m"]))
    ]
