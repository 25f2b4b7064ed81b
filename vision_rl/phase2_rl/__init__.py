"""Phase 2: SAC (Stable-Baselines3) driving policies on the frozen frame embedding plus dedicated features, or on
the privileged state, and the policy artifact.

:func:`.train.train_policy` trains, :func:`.evaluate.evaluate_policy` times a policy with the lap-time protocol
(:mod:`vision_rl.evaluation`). Import those modules directly (they pull in torch and Stable-Baselines3); this
package root imports only the artifact helpers.
"""

from vision_rl.phase2_rl.artifact import (
    LoadedPolicy,
    PolicyDriver,
    PolicyError,
    PolicySpec,
    check_encoder,
    load_policy,
)

__all__ = ["LoadedPolicy", "PolicyDriver", "PolicyError", "PolicySpec", "check_encoder", "load_policy"]
