"""What the SAC-family trainers share: the save clock, the metrics file, the samplers' set-up (the presets and a
run's overrides: :mod:`.presets`)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from vision_rl.envs.core import RacingConfig
from vision_rl.envs.observations import ObsNormalizer
from vision_rl.files import parse_json
from vision_rl.training.artifact import racing_config_to_dict

METRICS_NAME = "metrics.jsonl"


def gamma_per_step(gamma_per_tenth_s: float, control_dt_s: float) -> float:
    """The discount of one control step of ``control_dt_s`` seconds, given the discount per 0.1 s (the presets'
    and --gamma's unit), so that a finer control step keeps the horizon in seconds."""
    return gamma_per_tenth_s ** (control_dt_s / 0.1)


def torch_device(name: str) -> str:
    """``auto`` -> ``cuda`` when a GPU is visible, else ``cpu``; other names as given."""
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


#: ``progress(num_timesteps, total_steps, last_evaluation_or_None)``, called as training goes.
Progress = Callable[[int, int, "dict[str, Any] | None"], None]


def next_multiple(n: int, every: int) -> int | None:
    """The first multiple of ``every`` after ``n`` (None when ``every`` is 0: never)."""
    return None if every <= 0 else (n // every + 1) * every


class SaveClock:
    """When a trainer saves: all of it (the replay buffer too) every ``every_steps`` environment steps, weights and
    counters alone every ``every_min`` minutes of wall-clock time; 0 turns either off."""

    def __init__(self, start_steps: int, every_steps: int, every_min: float) -> None:
        self.every_steps, self.every_s = every_steps, 60.0 * every_min
        self.next_full = next_multiple(start_steps, every_steps)
        self.last_save_s = time.perf_counter()

    def due(self, n: int) -> str | None:
        """``full``, ``light`` or None at step ``n``; a save restarts the minute count."""
        kind = None
        if self.next_full is not None and n >= self.next_full:
            self.next_full = next_multiple(n, self.every_steps)
            kind = "full"
        elif self.every_s > 0 and time.perf_counter() - self.last_save_s >= self.every_s:
            kind = "light"
        if kind is not None:
            self.last_save_s = time.perf_counter()
        return kind


def sampler_setup(
    racing: RacingConfig,
    kind: str,
    normalizer: ObsNormalizer,
    fingerprint: dict[str, Any],
    hidden_units: tuple[int, ...],
    seed: int,
    encoder_path: Path | None = None,
    encoder_runtime: str = "auto",
    label_skill: float | None = None,
) -> Any:
    """What the sampler actors of a run build their world and policy from (``label_skill``: the built-in AI's skill
    that labels the states they visit; None: no labels)."""
    from vision_rl.training.distributed import SamplerSetup, portable_track

    config = {**racing_config_to_dict(racing), "track": portable_track(racing.track)}
    return SamplerSetup(
        racing_config=config,
        observation=kind,
        obs_normalizer=normalizer.to_dict(),
        fingerprint=fingerprint,
        hidden_units=tuple(hidden_units),
        seed=seed,
        encoder_path=str(encoder_path.resolve()) if encoder_path is not None else "",
        encoder_runtime=encoder_runtime,
        label_skill=label_skill,
    )


def read_metrics(path: str | os.PathLike[str], events: bool = False) -> list[dict[str, Any]]:
    """The evaluation records of a run's metrics.jsonl (a torn last line, from a kill mid-write, is skipped); with
    ``events`` also the lines that record events (a lost sampler: ``{"event": "sampler_lost", ...}``).

    A run killed after an evaluation resumes from its last checkpoint, which may be older, and evaluates those steps
    again with the policy that now exists: an evaluation at step N drops the earlier ones at N or later, so every
    record left belongs to the run's history."""
    records: list[dict[str, Any]] = []
    for line in Path(path).read_text().splitlines():
        try:
            record = parse_json(line)
        except ValueError:
            continue
        if not isinstance(record, dict):  # a line damaged into another JSON value
            continue
        if "event" not in record and "num_timesteps" in record:
            step = record["num_timesteps"]
            records = [r for r in records if "event" in r or r.get("num_timesteps", -1) < step]
            records.append(record)
        elif events or "event" not in record:
            records.append(record)
    return records
