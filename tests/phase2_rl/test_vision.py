"""The vision path: frames embedded inside the vector env, feature statistics, a tiny vision run, the hash check."""

from __future__ import annotations

import numpy as np
import pytest

from tests.phase2_rl.conftest import renderer_available, tiny_train_config
from vision_rl.envs import RacingConfig, make_sb3_vec_env
from vision_rl.phase1_repr import checkpoint_sha256, load_encoder
from vision_rl.phase2_rl.artifact import Observer, PolicyError, PolicySpec, load_policy
from vision_rl.phase2_rl.evaluate import evaluate_policy
from vision_rl.phase2_rl.train import train_policy
from vision_rl.phase2_rl.vision_env import EmbeddingVecEnv, sample_vision_statistics

_REASON = renderer_available()
pytestmark = pytest.mark.skipif(bool(_REASON), reason=_REASON or "renderer available")


def test_embedding_env_returns_75d_vectors_and_embeds_terminal_frames(small_track, tiny_encoders):
    cfg = RacingConfig(track=small_track, observation="vision", n_groups=2, image_size_px=(96, 64), episode_s=0.3)
    venv = make_sb3_vec_env(cfg, seed=0)
    encoder = load_encoder(tiny_encoders[0])
    rng_before = venv.core.rng
    stats = sample_vision_statistics(venv.core, encoder, steps=4)
    assert venv.core.rng is rng_before
    assert stats.offset.shape == (75,)
    assert stats.offset[64] > 5.0  # body-frame forward speed of the driving AI, m/s
    observer = Observer("vision", stats, encoder)
    env = EmbeddingVecEnv(venv, observer)
    obs = env.reset()
    assert obs.shape == (2, 75) and obs.dtype == np.float32 and env.observation_space.shape == (75,)
    raw = venv.core.observation()  # the same state rendered again: frames are a pure function of the poses
    expected = (np.hstack([encoder(raw["image"]).numpy(), raw["features"]]) - stats.offset) / stats.scale
    np.testing.assert_allclose(obs, expected, rtol=1e-4, atol=1e-4)
    for _ in range(3):
        obs, _, dones, infos = env.step(np.zeros((2, 2), dtype=np.float32))
    assert dones.all()  # 0.3 s episodes: three steps
    terminal = np.stack([info["terminal_observation"] for info in infos])
    assert terminal.shape == (2, 75) and not np.allclose(terminal, obs)  # the old episode's end, not the new start
    env.close()


def test_vision_policy_records_its_encoder_and_refuses_another(small_track, tiny_encoders, tmp_path):
    enc_a, enc_b = tiny_encoders
    out = tmp_path / "vision"
    result = train_policy(tiny_train_config(small_track, out, encoder=str(enc_a), steps=120, learning_starts=40,
                                            stats_steps=3, eval_every_steps=60))  # fmt: skip
    assert result["observation"] == "vision" and result["num_timesteps"] == 120
    spec = PolicySpec.read(out / "policy.json")
    assert spec.encoder["sha256"] == checkpoint_sha256(enc_a) and spec.encoder["input_hw_px"] == [64, 96]
    assert spec.config.image_size_px == (96, 64) and len(spec.obs_normalizer["offset"]) == 75
    with pytest.raises(PolicyError, match="trained with encoder sha256"):
        load_policy(out, encoder=enc_b)
    with pytest.raises(PolicyError, match="trained with encoder sha256"):
        evaluate_policy(out, encoder=str(enc_b))
    with pytest.raises(PolicyError, match="trained with encoder sha256"):
        train_policy(tiny_train_config(small_track, out, encoder=str(enc_b), resume=True, steps=160))
    ev = evaluate_policy(out, encoder=str(enc_a), seeds=1, time_limit_s=5.0)
    assert ev["observation"] == "vision" and ev["encoder_sha256"] == spec.encoder["sha256"]
    assert ev["seeds"][0]["distance_m"] != 0.0
