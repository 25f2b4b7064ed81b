"""What the three papers' agents share: pickle-free agent and buffer files, the policy artifact and its driver, the
SAC presets and save clock, interrupts, the Ray samplers and their pacing, and a policy's evaluation."""
