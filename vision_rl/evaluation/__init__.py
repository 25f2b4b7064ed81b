"""Evaluation: the one lap-time protocol for every driver (:mod:`.protocol`), its outputs (plots, videos) and the
leaderboard built only from its results (:mod:`.leaderboard`)."""

from vision_rl.evaluation.protocol import PROTOCOL_VERSION, BuiltinAI, Driver, LapRecord, LapTiming, SeedRun, time_laps

__all__ = ["PROTOCOL_VERSION", "BuiltinAI", "Driver", "LapRecord", "LapTiming", "SeedRun", "time_laps"]
