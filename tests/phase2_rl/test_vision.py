"""The vision path: frames embedded inside the vector env, feature statistics, a tiny vision run, the hash check."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.policies import tiny_train_config
from tests.helpers.rendering import renderer_available
from vision_rl.envs import RacingConfig, make_sb3_vec_env
from vision_rl.envs.observations import ObsNormalizer
from vision_rl.envs.observer import Observer
from vision_rl.phase1_repr import file_sha256, load_encoder
from vision_rl.phase2_rl.train import train_policy
from vision_rl.training.artifact import PolicyError, PolicySpec, load_policy
from vision_rl.training.evaluate import evaluate_policy

_REASON = renderer_available()
pytestmark = pytest.mark.skipif(bool(_REASON), reason=_REASON or "renderer available")


def test_the_observer_embeds_frames_inside_the_vector_env_terminal_frames_included(small_track, tiny_encoders):
    cfg = RacingConfig(track=small_track, observation="vision", n_groups=2, image_hw_px=(64, 96), episode_s=0.3)
    venv = make_sb3_vec_env(cfg, seed=0)
    core = venv.core
    encoder = load_encoder(tiny_encoders[0])
    observer = Observer("vision", core.track, core.car, core.groups, None, encoder, cfg.image_hw_px)
    rngs_before = core.group_rngs
    stats = ObsNormalizer.from_samples("vision", core.sample_raw_observations(observer, steps=4))
    assert core.group_rngs is rngs_before
    assert stats.offset.shape == (75,)
    assert stats.offset[64] > 5.0  # body-frame forward speed of the driving AI, m/s
    observer.normalizer = stats
    core.observer = observer
    obs = venv.reset()
    assert obs.shape == (2, 75) and obs.dtype == np.float32 and observer.space.shape == (75,)
    frames = observer.frames(core.world.state, core.ego_ids)  # frames are a pure function of the poses
    features = Observer("vision", core.track, core.car, core.groups, image_hw_px=cfg.image_hw_px)(
        core.world.state, core.ego_ids
    )["features"]
    expected = (np.hstack([encoder(frames).numpy(), features]) - stats.offset) / stats.scale
    np.testing.assert_allclose(obs, expected, rtol=1e-4, atol=1e-4)
    for _ in range(3):
        venv.step_async(np.zeros((2, 2), dtype=np.float32))
        obs, _, dones, infos = venv.step_wait()
    assert dones.all()  # 0.3 s episodes: three steps
    terminal = np.stack([info["terminal_observation"] for info in infos])
    assert terminal.shape == (2, 75) and not np.allclose(terminal, obs)  # the old episode's end, not the new start
    venv.close()


def test_vision_policy_records_its_encoder_and_refuses_another(small_track, tiny_encoders, tmp_path):
    enc_a, enc_b = tiny_encoders
    out = tmp_path / "vision"
    result = train_policy(
        tiny_train_config(
            small_track, out, encoder=str(enc_a), steps=120, learning_starts=40, stats_steps=3, eval_every_steps=60
        )
    )
    assert result["observation"] == "vision" and result["num_timesteps"] == 120
    spec = PolicySpec.read(out / "policy.json")
    assert spec.encoder["sha256"] == file_sha256(enc_a) and spec.encoder["input_hw_px"] == [64, 96]
    assert spec.config.image_hw_px == (64, 96) and len(spec.obs_normalizer["offset"]) == 75
    with pytest.raises(PolicyError, match="trained with encoder sha256"):
        load_policy(out, encoder=enc_b)
    with pytest.raises(PolicyError, match="trained with encoder sha256"):
        evaluate_policy(out, encoder=str(enc_b))
    with pytest.raises(PolicyError, match="trained with encoder sha256"):
        train_policy(
            tiny_train_config(small_track, out, encoder=str(enc_b), resume=True, steps=160, learning_starts=40)
        )
    ev = evaluate_policy(out, encoder=str(enc_a), seeds=1, time_limit_s=5.0, encoder_error=True)
    assert ev["driver"]["observation"] == "vision" and ev["driver"]["encoder_sha256"] == spec.encoder["sha256"]
    assert ev["seeds"][0]["distance_m"] != 0.0
    # No lap in 5 s: the encoder's error over the whole run's 50 steps, and over the built-in AI's scored lap.
    errors = ev["encoder_error"]
    assert errors["policy"]["all"]["frames"] == 50 and errors["built_in_ai"]["all"]["frames"] > 50
    assert errors["built_in_ai"]["wall_contact"]["frames"] == 0 and np.isfinite(errors["policy"]["all"]["heading"])
    from vision_rl.commands.evaluate import format_timing

    text = format_timing(ev)
    assert "all: 50 / " in text[2] and text[3].startswith("  edge_rays (m): all ")
