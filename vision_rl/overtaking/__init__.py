"""The overtaking paper: the 3-stage curriculum (Agents 1-3) and standard SAC, settings A/B and Fig. 3, the
demonstrations, the Table III baselines (BC, GAIL, TD3, SAC, Dreamer) and human driving (``play``)."""
