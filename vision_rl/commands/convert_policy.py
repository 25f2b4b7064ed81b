"""`vision-rl convert-policy`: a run folder of an older format to this one (format 2, a Stable-Baselines3 zip, to
weights without pickle; format 3 sealed with its content hashes)."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.commands.output import emit


@dataclass(frozen=True)
class ConvertPolicyOptions:
    """Convert a train-policy run folder of an older format in place: format 2 (policy.zip) to policy.pt, reading
    only the zip's tensors and plain counters, so nothing in it can run (the pickled replay buffer is not read: a
    resumed run collects a new one); format 3 sidecars and replay buffers sealed with their content hashes once
    their weights' checksums are checked."""

    run: str = ""
    """The run folder (holding policy.json) (required)."""
    json: bool = False
    """Print the files written as JSON."""


def run_convert_policy(opts: ConvertPolicyOptions) -> int:
    from vision_rl.training.artifact import convert_run

    written = convert_run(opts.run)
    emit({"written": [str(p) for p in written]}, opts.json)
    return 0
