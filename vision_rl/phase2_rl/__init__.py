"""Phase 2: SAC (Stable-Baselines3) driving policies on the frozen frame embedding plus dedicated features, or on
the privileged state; the papers' time-trial evaluation protocol and the lap-time leaderboard.

Commands (config dataclass, runner): ``TrainPolicyConfig``/``run_train_policy`` in :mod:`.train`,
``EvaluateConfig``/``run_evaluate`` in :mod:`.evaluate`, ``LeaderboardConfig``/``run_leaderboard`` in
:mod:`.leaderboard`; :func:`.pipeline.pipeline_phase2` is the second half of ``vision-rl pipeline``. Import those
modules directly (they pull in torch and Stable-Baselines3); this package root imports only the artifact helpers.
"""

from vision_rl.phase2_rl.artifact import (
    LoadedPolicy,
    Observer,
    PolicyError,
    PolicySpec,
    check_encoder,
    load_policy,
)

__all__ = ["LoadedPolicy", "Observer", "PolicyError", "PolicySpec", "check_encoder", "load_policy"]
