"""The SAC presets and a run's overrides of them: light (no torch or Stable-Baselines3), so that a command's options
can hold them and its ``--help`` answers without loading a trainer."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stable_baselines3.common.utils import LinearSchedule


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
        from stable_baselines3.common.utils import LinearSchedule

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
    target_entropy: float = field(default=0.0, metadata={"min": None})
    """SAC's entropy target, nats (0: SB3's, -2 for the 2 action dimensions; lower: a less random policy in
    training)."""
    batch_size: int = 0
    """Override the preset's batch size (0: preset)."""
    buffer_size: int = 0
    """Override the preset's buffer size (0: preset)."""
    learning_starts: int = field(default=-1, metadata={"min": -1})
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
