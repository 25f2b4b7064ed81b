"""The fixed sets of values the options take, written out so that a command module stays importable without torch
(``tests/commands/test_choices.py`` holds each equal to the library constant it mirrors)."""

from __future__ import annotations

STEER_ACTIONS = ("angle", "rate", "speed_scaled", "rate_scaled")
"""vision_rl.envs.core.STEER_ACTIONS"""
WALL_PENALTY_SPEEDS = ("end", "impact")
"""vision_rl.envs.core.WALL_PENALTY_SPEEDS"""
SAC_PRESETS = ("paper", "cpu")
"""vision_rl.training.presets.PRESETS"""
ENCODER_RUNTIMES = ("torch", "onnxruntime", "auto")
"""vision_rl.phase1_repr.onnx_runtime.RUNTIMES"""
BACKBONES = ("s2d", "mobilenet_v3_small")
"""vision_rl.phase1_repr.encoder.BACKBONES"""
STRATEGIES = ("auto", "ddp")
"""vision_rl.phase1_repr.config.STRATEGIES"""
COMPRESSIONS = ("zstd", "gzip", "lzf", "none")
"""vision_rl.capture.h5format.COMPRESSIONS"""
DDPG_VARIANTS = ("asymmetric", "symmetric", "state-actor")
"""vision_rl.ddpg.config.VARIANTS"""
OVERTAKING_AGENTS = ("1", "2", "3", "standard")
"""vision_rl.overtaking.config.AGENTS"""
BASELINE_ALGOS = ("bc", "gail", "td3", "sac", "dreamer")
"""vision_rl.overtaking.baselines.ALGOS"""
SETTINGS = ("A", "B")
"""vision_rl.overtaking.settings.SETTINGS"""

#: The options of train-policy, experiment and tune with a fixed set of values.
POLICY_CHOICES = {
    "steer_action": STEER_ACTIONS,
    "wall_penalty_speed": WALL_PENALTY_SPEEDS,
    "preset": SAC_PRESETS,
    "encoder_runtime": ENCODER_RUNTIMES,
}
