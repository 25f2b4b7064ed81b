"""What the SAC-family trainers share: the presets, the save clock, the metrics file, the samplers' set-up."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from stable_baselines3.common.utils import LinearSchedule

from vision_rl.envs.core import RacingConfig
from vision_rl.envs.observations import ObsNormalizer
from vision_rl.training.artifact import racing_config_to_dict

METRICS_NAME = "metrics.jsonl"


@dataclass(frozen=True)
class SACPreset:
    """SAC hyper-parameters. Steps count transitions over all cars (SB3's ``num_timesteps``)."""

    hidden_units: tuple[int, ...]
    """Widths of the hidden layers of actor and critics (ReLU)."""
    batch_size: int
    """Transitions per gradient update."""
    buffer_size: int
    """Replay buffer capacity, transitions."""
    learning_starts: int
    """Transitions collected with random actions before the first update."""
    learning_rate: float
    """Adam step size of actor, critics and entropy coefficient."""
    gamma: float
    """Discount per 0.1 s (SAC's per-step discount is :func:`gamma_per_step` of it)."""
    tau: float
    """Polyak factor of the target critics."""
    train_freq_steps: int
    """Vector-env steps (n_cars transitions each) between training phases."""
    gradient_steps: int
    """Gradient updates per training phase."""
    torch_threads: int
    """torch intra-op threads (0: leave torch's default)."""
    learning_rate_final: float = 0.0
    """Adam step size at the run's last step, reached linearly from ``learning_rate`` (0: constant)."""
    target_entropy: float = 0.0
    """Entropy the policy is held at by the learned coefficient, nats (0: SB3's ``auto``, minus the action's
    dimensions)."""

    def learning_rate_schedule(self) -> float | LinearSchedule:
        """SB3's ``learning_rate``: constant, or falling linearly to the run's last step (by SB3's progress, so a
        run resumed to more steps spreads what is left of the fall over its new total)."""
        if self.learning_rate_final <= 0:
            return self.learning_rate
        return LinearSchedule(self.learning_rate, self.learning_rate_final, end_fraction=1.0)


PRESETS: dict[str, SACPreset] = {
    # The vision paper, section 4, and Fuchs et al.: MLP 2 x 256 (ReLU), batch 4,096, buffer 1e6, 40k random
    # start steps, lr 1e-3, gamma 0.99. One update per vector step of 20 cars is our choice (the papers update
    # after each "epoch" of 20 trials on the console).
    "paper": SACPreset((256, 256), 4096, 1_000_000, 40_000, 1e-3, 0.99, 0.005, 1, 1, 0),
    # Chosen by measurement on the shared 2-core CPU: SB3 SAC 2 x 256 on one thread did 63 updates/s at batch 256,
    # 42 at 512 and 24 at 1,024 (about 6 at 4,096), and a vector step of 20 state cars costs about
    # 1.2 ms, so one update per vector step spends ~90 % of the time on updates and still collects ~1,100
    # transitions/s. With lr 1e-3 (the paper's) the agent drove two whole laps of the expressway after 200k steps
    # (3 min); with 3e-4 after 300k; both then stayed at 2:16-2:21 over 20-40 min of training. One torch
    # thread leaves the other core to the simulator and to neighbours.
    "cpu": SACPreset((256, 256), 256, 1_000_000, 10_000, 1e-3, 0.99, 0.005, 1, 1, 1),
}


@dataclass(frozen=True)
class SACOverrides:
    """A preset by name and the hyper-parameters a run overrides (0, -1 or empty: the preset's)."""

    preset: str = "cpu"
    """`paper` (the paper's SAC recipe) or `cpu` (learns on 2 cores)."""
    learning_rate: float = 0.0
    """Override the preset's learning rate (0: preset)."""
    learning_rate_final: float = 0.0
    """Let the learning rate fall linearly to this by the run's last step (0: constant; not in the papers)."""
    target_entropy: float = 0.0
    """SAC's entropy target, nats (0: SB3's, -2 for the 2 action dimensions; lower: a less random policy in
    training)."""
    batch_size: int = 0
    """Override the preset's batch size (0: preset)."""
    buffer_size: int = 0
    """Override the preset's buffer size (0: preset)."""
    learning_starts: int = -1
    """Override the preset's random start steps (-1: preset)."""
    gradient_steps: int = 0
    """Override the preset's updates per vector step (0: preset)."""
    gamma: float = 0.0
    """Override the preset's discount per 0.1 s step (0: preset)."""
    hidden_units: str = ""
    """Override the preset's hidden layer widths of actor and critics, e.g. 128,128 (empty: preset)."""


def parse_hidden_units(text: str) -> tuple[int, ...]:
    """``"128,128"`` -> (128, 128); empty -> (); a non-positive or non-integer width is refused."""
    try:
        units = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        units = (0,)
    if any(u < 1 for u in units):
        raise ValueError(f"--hidden-units {text!r}: give positive layer widths separated by commas, e.g. 256,256")
    return units


def resolve_preset(cfg: SACOverrides | Any) -> SACPreset:
    """The preset ``cfg.preset`` with ``cfg``'s overrides (0, -1 or empty: the preset's): a :class:`SACOverrides`,
    or a trainer's config with its fields (gamma, hidden_units, learning_rate_final and target_entropy optional)."""
    if cfg.preset not in PRESETS:
        raise ValueError(f"--preset must be one of {sorted(PRESETS)}, got {cfg.preset!r}")
    preset = PRESETS[cfg.preset]
    gamma, hidden = getattr(cfg, "gamma", 0.0), parse_hidden_units(getattr(cfg, "hidden_units", ""))
    overrides = {
        "learning_rate": cfg.learning_rate if cfg.learning_rate > 0 else None,
        "learning_rate_final": getattr(cfg, "learning_rate_final", 0.0) or None,
        "target_entropy": getattr(cfg, "target_entropy", 0.0) or None,
        "batch_size": cfg.batch_size if cfg.batch_size > 0 else None,
        "buffer_size": cfg.buffer_size if cfg.buffer_size > 0 else None,
        "learning_starts": cfg.learning_starts if cfg.learning_starts >= 0 else None,
        "gradient_steps": cfg.gradient_steps if cfg.gradient_steps > 0 else None,
        "gamma": gamma if gamma > 0 else None,
        "hidden_units": hidden or None,
    }
    return dataclasses.replace(preset, **{k: v for k, v in overrides.items() if v is not None})


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
            record = json.loads(line)
        except ValueError:
            continue
        if "event" not in record and "num_timesteps" in record:
            step = record["num_timesteps"]
            records = [r for r in records if "event" in r or r.get("num_timesteps", -1) < step]
            records.append(record)
        elif events or "event" not in record:
            records.append(record)
    return records
