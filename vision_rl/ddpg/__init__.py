"""The DDPG paper: the asymmetric actor-critic (pixel actor, state critic) and its symmetric and state-only
variants, training with time-based checkpoints, Ray samplers, the lap reward profile and the equal-time
comparison."""
