"""A policy driving under the protocol sees what it saw in training: the same observation, frame delay included."""

import numpy as np

from vision_rl.envs.core import RacingConfig, RacingCore
from vision_rl.phase2_rl.artifact import PolicyDriver


class _MeanColour:
    """A stand-in encoder: each frame's mean colour per half (6-D), enough to tell frames apart."""

    rep_dim = 6

    def __call__(self, frames):
        h = frames.shape[2] // 2
        return np.hstack([frames[:, :, :h].mean(axis=(1, 2)), frames[:, :, h:].mean(axis=(1, 2))])


def test_driver_observations_equal_the_environments_with_a_frame_delay(gl_available):
    cfg = RacingConfig(track="technical", observation="vision", n_groups=2, image_hw_px=(24, 40), frame_delay_s=0.15)
    core = RacingCore(cfg, seed=1)
    core.observer.encoder = _MeanColour()
    core.reset_groups(np.arange(2))
    seen = []
    actions = np.array([[0.2, 1.0], [-0.2, 0.8]])
    driver = PolicyDriver(lambda obs: seen.append(obs.copy()) or actions, "vision", None, _MeanColour(),
                          cfg.image_hw_px, cfg.control_dt_s, frame_delay_s=cfg.frame_delay_s)  # fmt: skip
    driver.reset(core.world, core.ego_ids)
    env_obs = [core.observation()]
    for _ in range(4):
        driver.act(core.world.state)
        env_obs.append(core.step(actions, autoreset=False)[0])
    driver.act(core.world.state)
    np.testing.assert_allclose(np.stack(seen), np.stack(env_obs), rtol=1e-6)
    assert not np.allclose(seen[4][:, :6], seen[2][:, :6])  # the frames do change over the steps compared
    driver.close()
    core.observer.close()



def test_a_driver_for_a_config_observes_and_steers_as_that_environment():
    # Regression: train-policy's periodic evaluation once built its driver without the frame delay and the steering
    # action of the run's environment, so its learning curves timed another policy than the one saved.
    cfg = RacingConfig(track="technical", observation="vision", image_hw_px=(24, 40), control_dt_s=0.2,
                       frame_delay_s=0.1, steer_action="speed_scaled", pedal_full_at=0.9)  # fmt: skip
    driver = PolicyDriver.for_config(lambda obs: obs, "vision", None, _MeanColour(), cfg)
    assert (driver.image_hw_px, driver.control_dt_s, driver.frame_delay_s, driver.steer_action,
            driver.pedal_full_at) == ((24, 40), 0.2, 0.1, "speed_scaled", 0.9)  # fmt: skip
