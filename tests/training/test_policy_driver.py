"""A policy driving under the protocol sees what it saw in training: the same observation, frame delay included."""

import numpy as np
import torch

from vision_rl.envs.core import RacingConfig, RacingCore
from vision_rl.evaluation.protocol import time_laps
from vision_rl.phase1_repr.checkpoint import load_encoder
from vision_rl.training.artifact import PolicyDriver


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
    driver = PolicyDriver(lambda obs: seen.append(obs.copy()) or actions, "vision", None, _MeanColour(), cfg)
    driver.reset(core.world, core.ego_ids)
    env_obs = [core.observation()]
    for _ in range(4):
        driver.act(core.world.state)
        env_obs.append(core.step(actions, autoreset=False)[0])
    driver.act(core.world.state)
    seen_obs = np.stack(seen)
    assert seen_obs.shape[1] == 3 and np.array_equal(seen_obs[:, 2], seen_obs[:, 1])  # padded to 3 with the last car
    np.testing.assert_allclose(seen_obs[:, :2], np.stack(env_obs), rtol=1e-6)
    assert not np.allclose(seen_obs[4, :, :6], seen_obs[2, :, :6])  # the frames do change over the steps compared
    driver.close()
    core.observer.close()


def test_a_start_drives_the_same_beside_any_number_of_others(gl_available, tiny_encoders):
    # A batch's size changes a network's products in the last bit, and laps are chaotic in that bit: a vision
    # policy's start 0 once lapped in 2:11.385 among 13 starts and in 2:13.090 among the protocol's 3. The driver
    # renders, embeds and acts in batches of 3, so 7 starts drive as the runs of starts 0-2, 3-5 and 6-8, and start 0
    # alone as among the others.
    encoder = load_encoder(tiny_encoders[0])
    torch.manual_seed(0)
    actor = torch.nn.Sequential(
        torch.nn.Linear(encoder.rep_dim + 11, 256),
        torch.nn.ReLU(),
        torch.nn.Linear(256, 256),
        torch.nn.ReLU(),
        torch.nn.Linear(256, 2),
        torch.nn.Tanh(),
    )

    def predict(obs):
        with torch.no_grad():
            return actor(torch.as_tensor(obs)).numpy()

    def drive(seeds):
        driver = PolicyDriver(predict, "vision", None, encoder, RacingConfig(image_hw_px=encoder.input_hw_px))
        timing = time_laps(driver, "technical", "hatchback", seeds, laps=1, time_limit_s=3.0, record=True)
        driver.close()
        return np.stack([timing.x_m, timing.yaw_rad, timing.steer_rad, timing.omega])

    together = drive(range(7))
    apart = np.concatenate([drive([0, 1, 2]), drive([3, 4, 5]), drive([6, 7, 8])[..., :1]], axis=2)
    assert together.shape == apart.shape == (4, 30, 7)
    assert np.array_equal(together, apart)
    assert np.array_equal(drive([0]), together[..., :1])  # fewer than 3 starts: the batch is padded to 3 as well
    assert not np.array_equal(together[2, :, 0], together[2, :, 1])  # the starts steer differently
