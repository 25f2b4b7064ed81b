"""The parts of a trainer's config that every trainer has: when it evaluates, when it saves, where it samples."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EvaluationSchedule:
    """When a trainer times its current policy with the lap-time protocol."""

    every_steps: int = 100_000
    """Evaluate the current policy every N steps (0: off)."""
    seeds: int = 1
    """Start seeds of the periodic evaluation."""
    laps: int = 2
    """Laps of the periodic evaluation (the last is scored)."""


@dataclass(frozen=True)
class CheckpointSchedule:
    """When a trainer saves: all of it every ``every_steps`` steps, weights and counters every ``every_min``."""

    every_steps: int = 200_000
    """Save weights, buffer and a snapshot every N steps (0: off)."""
    every_min: float = 10.0
    """Save weights, optimisers and counters (not the buffer) every N minutes of wall-clock time (0: off)."""


@dataclass(frozen=True)
class SamplerOptions:
    """Sampling in Ray actors while the trainer's process learns (leave ``workers`` None to sample in-process)."""

    workers: int | None = None
    """Sampler actors (Ray), each a world of --cars cars in its own process, while this process learns; leave it out
    to sample in this process."""
    address: str = ""
    """With --workers: the Ray cluster to join (auto, host:port or ray://host:port); empty: start one here."""
    max_staleness: int = 1
    """With --workers: weight versions a sampler's policy may lag the learner's (0: synchronous)."""
    version_every_updates: int = 20
    """With --workers: learner updates per weight version sent to the samplers."""
