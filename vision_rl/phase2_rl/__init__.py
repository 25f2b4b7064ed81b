"""The vision paper's Phase 2: SAC on the 38-D state or on the frozen 64-D embedding plus 11 features.

:func:`.train.train_policy` trains one run, :mod:`.experiment` runs a recipe over training seeds, :mod:`.tune`
searches recipes, :mod:`.guide` labels states with the built-in AI. The policy artifact they write is
:mod:`vision_rl.training.artifact`'s.
"""
