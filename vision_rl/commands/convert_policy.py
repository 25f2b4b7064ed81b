"""`vision-rl convert-policy`: a run folder of an older format to this one (format 2, a Stable-Baselines3 zip, to
weights without pickle; format 3 sealed with its content hashes), and a train-overtaking run folder's records sealed."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.commands.output import emit


@dataclass(frozen=True)
class ConvertPolicyOptions:
    """Convert a train-policy run folder of an older format in place: format 2 (policy.zip) to policy.pt, reading
    only the zip's tensors and plain counters, so nothing in it can run (the pickled replay buffer is not read: a
    resumed run collects a new one); format 3 sidecars and replay buffers sealed with their content hashes once
    their weights' checksums are checked. A train-overtaking run folder (holding run.json): each stage's policy as
    above, then its run.json, stage.json and agent records sealed once they agree with the checked policies."""

    run: str = ""
    """The run folder (holding policy.json, or a train-overtaking run's run.json) (required)."""
    json: bool = False
    """Print the files written as JSON."""


def run_convert_policy(opts: ConvertPolicyOptions) -> int:
    from pathlib import Path

    from vision_rl.overtaking.curriculum import RUN_NAME, convert_overtaking_run
    from vision_rl.training.artifact import convert_run

    overtaking = (Path(opts.run) / RUN_NAME).is_file()
    written = convert_overtaking_run(opts.run) if overtaking else convert_run(opts.run)
    emit({"written": [str(p) for p in written]}, opts.json)
    return 0
