"""Ctrl-C and SIGTERM stop a Stable-Baselines3 run between rollouts, never inside a step.

SB3's off-policy loop counts a vector step (``num_timesteps``) before it stores the step's transitions, and calls
the callback in between, where the trainers evaluate and save. An interrupt there saved a run whose counter was one
vector step ahead of its replay buffer (seen: 1,490 steps counted, 1,488 transitions stored, with 2 cars).
:func:`learn_between_interrupts` holds the first SIGINT or SIGTERM until the next rollout starts (the step stored,
the updates done) and acts on it there as its handler would have; a second one acts at once. A signal whose
handler is the system's (``SIG_DFL``, ``SIG_IGN``) is left alone: only what would have raised in Python waits."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.callbacks import BaseCallback, CallbackList

from vision_rl.signals import HeldSignal
from vision_rl.sim.world import NonFiniteInputError


class _ReleaseAtRolloutStart(BaseCallback):
    def __init__(self, held: HeldSignal) -> None:
        super().__init__()
        self.held = held

    def _on_rollout_start(self) -> None:
        self.held.release()

    def _on_step(self) -> bool:
        return True


class TrainingDivergedError(ValueError):
    """The networks' outputs became NaN or infinite: what follows would only train on garbage."""


def learn_between_interrupts(model: Any, callback: BaseCallback, **learn_kwargs: Any) -> Any:
    """``model.learn(callback=callback, **learn_kwargs)`` with the first interrupt held to a rollout's start. A
    policy whose outputs became non-finite (torch's distribution check: a multi-line message with the tensor) is
    one line, :class:`TrainingDivergedError`; the run folder keeps what it last saved."""
    held = HeldSignal()
    with held.installed():
        try:
            return model.learn(callback=CallbackList([callback, _ReleaseAtRolloutStart(held)]), **learn_kwargs)
        except ValueError as exc:
            # NaN outputs meet torch's distribution check, or, when they reach the actions first, the world's.
            if "found invalid values" not in str(exc) and not isinstance(exc, NonFiniteInputError):
                raise
            raise TrainingDivergedError(
                f"training diverged at step {getattr(model, 'num_timesteps', '?')}: the policy's outputs became NaN "
                "or infinite (a learning rate or reward weight too large?); the run folder keeps what it last saved"
            ) from None
