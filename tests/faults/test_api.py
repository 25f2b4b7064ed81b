"""The Python API and the registered environments given bad arguments: a ValueError that says what, never an
OverflowError or TypeError from deep inside, and never an argument dropped without a word."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import vision_rl


def _still(obs):
    return np.zeros((len(obs), 2), np.float32)


@pytest.mark.parametrize(
    ("what", "kwargs", "message"),
    [
        (
            "vision_rl.evaluate(time_limit_s=nan) (driven with the default limit before)",
            {"time_limit_s": np.nan},
            "time_limit_s must be",
        ),
        (
            "vision_rl.evaluate(time_limit_s=inf) (OverflowError before)",
            {"time_limit_s": np.inf},
            "time_limit_s must be",
        ),
        ("vision_rl.evaluate(seeds='3') (TypeError before)", {"seeds": "3"}, "seeds must be a whole number"),
        ("vision_rl.evaluate(laps=2.0)", {"laps": 2.0}, "laps must be a whole number"),
    ],
)
def test_evaluate_refuses_bad_protocol_arguments_before_driving(small_track, what, kwargs, message, fault):
    with pytest.raises(ValueError, match=message) as excinfo:
        vision_rl.evaluate(
            _still, env_id="vision_rl/TimeTrial-v2", name="x", write=False, track=small_track, **{"seeds": 1, **kwargs}
        )
    fault.refused(what, str(excinfo.value))


@pytest.mark.parametrize(
    ("what", "env_id", "kwargs", "message"),
    [
        (
            "gym.make TimeTrial episode_s=nan (bare ValueError from round)",
            "vision_rl/TimeTrial-v2",
            {"episode_s": np.nan},
            "episode_s must be",
        ),
        (
            "gym.make TimeTrial episode_s=1e308 (OverflowError before)",
            "vision_rl/TimeTrial-v2",
            {"episode_s": 1e308},
            "episode_s must be",
        ),
        ("gym.make Overtaking n_groups=0 (ignored before)", "vision_rl/Overtaking-v2", {"n_groups": 0}, "n_groups=0"),
    ],
)
def test_a_registered_environment_refuses_bad_arguments(small_track, what, env_id, kwargs, message, fault):
    with pytest.raises(ValueError, match=message) as excinfo:
        gym.make(env_id, track=small_track, **kwargs)
    fault.refused(what, str(excinfo.value))


@pytest.mark.parametrize("action", [np.zeros(7), np.zeros(1), np.zeros((2, 2))])
def test_an_action_of_the_wrong_shape_names_the_action(small_track, action, fault):
    env = gym.make("vision_rl/TimeTrial-v2", track=small_track)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"an action is \[steering, pedal\], shape \(2,\): got shape") as excinfo:
        env.step(action)
    env.step(np.zeros(2, np.float32))  # the environment is still usable
    fault.refused(
        f"env.step with an action of shape {action.shape} (numpy's reshape message before)", str(excinfo.value)
    )
