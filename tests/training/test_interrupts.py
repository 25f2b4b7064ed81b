"""An interrupt inside a trainer's callback waits for the rollout's end, so the step counter matches the buffer."""

from __future__ import annotations

import signal

import gymnasium as gym
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

from vision_rl.signals import HeldSignal
from vision_rl.sim.world import NonFiniteInputError, WorldInputError
from vision_rl.training.interrupts import TrainingDivergedError, learn_between_interrupts


class _SignalAt(BaseCallback):
    """Sends ``signum`` ``times`` times to this process from inside the callback at step ``at``, where a
    trainer evaluates and saves: SB3 has counted the step and not yet stored it."""

    def __init__(self, at: int, signum: int = signal.SIGINT, times: int = 1) -> None:
        super().__init__()
        self.at, self.signum, self.times = at, signum, times
        self.stored_when_signalled: int | None = None

    def _on_step(self) -> bool:
        if self.num_timesteps == self.at:
            self.stored_when_signalled = self.model.replay_buffer.pos * self.model.n_envs
            for _ in range(self.times):
                signal.raise_signal(self.signum)
        return True


@pytest.fixture(autouse=True)
def python_sigint():
    """SIGINT raising KeyboardInterrupt, as in a terminal (a background job of a non-interactive shell, as CI
    may be, starts with SIGINT ignored)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _sac() -> SAC:
    env = make_vec_env(lambda: gym.make("Pendulum-v1"), n_envs=2, seed=0)
    return SAC(
        "MlpPolicy",
        env,
        learning_starts=10,
        batch_size=8,
        train_freq=(4, "step"),
        gradient_steps=1,
        policy_kwargs={"net_arch": [8]},
        seed=0,
        device="cpu",
    )


def test_plain_learn_stops_with_the_counter_ahead_of_the_buffer():
    """What the module mends: without it the interrupt lands between counting a step and storing it."""
    model = _sac()
    with pytest.raises(KeyboardInterrupt):
        model.learn(total_timesteps=200, callback=_SignalAt(40))
    assert model.num_timesteps == 40 and model.replay_buffer.pos * model.n_envs == 38


def test_the_interrupt_waits_for_the_rollout_to_end():
    model, callback = _sac(), _SignalAt(36)
    with pytest.raises(KeyboardInterrupt):
        learn_between_interrupts(model, callback, total_timesteps=200)
    assert callback.stored_when_signalled == 34
    # rollouts of 4 vector steps of 2 cars: the one under way (steps 33-40) runs to its end and is stored
    assert model.num_timesteps == 40 and model.replay_buffer.pos * model.n_envs == 40
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_second_signal_acts_at_once():
    model = _sac()
    with pytest.raises(KeyboardInterrupt):
        learn_between_interrupts(model, _SignalAt(34, times=2), total_timesteps=200)
    assert model.num_timesteps == 34 and model.replay_buffer.pos * model.n_envs == 32


def test_sigterm_waits_only_where_python_handles_it():
    calls = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: calls.append(signum))
    try:
        held = HeldSignal()
        with held.installed():
            signal.raise_signal(signal.SIGTERM)
            assert calls == [] and held.pending is not None
        assert calls == [signal.SIGTERM]  # acted on when the block ends
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        with HeldSignal().installed():
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # the system's action is left alone
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_run_that_ends_with_nothing_held_returns_normally():
    model = _sac()
    learn_between_interrupts(model, _SignalAt(-1), total_timesteps=40)
    assert model.num_timesteps == 40


@pytest.mark.parametrize(
    "error",
    [
        ValueError("Expected parameter loc ... found invalid values:\ntensor([[nan, nan]])"),
        NonFiniteInputError("steer_cmd_rad[0] = nan is not a finite number; pass a finite value for every car"),
    ],
)
def test_nan_outputs_are_one_line_whichever_check_meets_them_first(error):
    class Diverging:
        num_timesteps = 120

        def learn(self, **kwargs):
            raise error

    with pytest.raises(TrainingDivergedError, match="training diverged at step 120") as excinfo:
        learn_between_interrupts(Diverging(), _SignalAt(at=-1))
    assert "\n" not in str(excinfo.value)


def test_another_value_error_is_not_taken_for_divergence():
    class Failing:
        def learn(self, **kwargs):
            raise WorldInputError("steer_cmd_rad must be a number or an array of shape (2,), one per car")

    with pytest.raises(WorldInputError, match="one per car"):
        learn_between_interrupts(Failing(), _SignalAt(at=-1))
