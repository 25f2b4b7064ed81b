"""`vision-rl convert-policy`: a policy of format 2 (a Stable-Baselines3 zip) to format 3 (no pickle)."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.commands.output import emit


@dataclass(frozen=True)
class ConvertPolicyOptions:
    """Convert a train-policy run folder of format 2 (policy.zip) to format 3 (policy.pt), in place. Only the zip's
    tensors and plain counters are read, so nothing in it can run; the pickled replay buffer is not read (a resumed
    run collects a new one)."""

    run: str = ""
    """The run folder (holding policy.json and policy.zip)."""
    json: bool = False
    """Print the files written as JSON."""


def run_convert_policy(opts: ConvertPolicyOptions) -> int:
    from vision_rl.training.artifact import convert_sb3_run

    if not opts.run:
        raise ValueError("convert-policy needs --run: a train-policy run folder of format 2")
    written = convert_sb3_run(opts.run)
    emit({"written": [str(p) for p in written]}, opts.json)
    return 0
