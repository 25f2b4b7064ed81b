"""`evaluate-ddpg`: a train-ddpg agent through the lap-time protocol."""

from __future__ import annotations

from dataclasses import dataclass

from vision_rl.commands.output import emit


@dataclass(frozen=True)
class EvaluateDDPGOptions:
    """Time a train-ddpg agent with the lap-time protocol on its own track and car (two laps, the second scored,
    best and median over start seeds); stores evaluation.json beside the agent."""

    agent: str = ""
    """A train-ddpg run folder or its ddpg.pt."""
    variant: str = ""
    """Refuse an agent of another variant (asymmetric, symmetric, state-actor; empty: any)."""
    seeds: int = 3
    """Start seeds, driven at once."""
    laps: int = 2
    """Consecutive laps; the last one is the score."""
    time_limit_s: float = 0.0
    """Stop a run after this long, s (0: 3 x the limit lap time per lap)."""
    save: bool = True
    """Write evaluation.json beside the agent."""
    json: bool = False
    """Print the result as JSON."""


def run_evaluate_ddpg(opts: EvaluateDDPGOptions) -> int:
    from vision_rl.commands.evaluate import format_timing
    from vision_rl.phase2_rl.ddpg_train import evaluate_ddpg

    if not opts.agent:
        raise ValueError("--agent is required: a train-ddpg run folder or its ddpg.pt")
    if opts.seeds < 1 or opts.laps < 1 or opts.time_limit_s < 0:
        raise ValueError("--seeds and --laps must be >= 1 and --time-limit-s >= 0")
    result = evaluate_ddpg(opts.agent, opts.seeds, opts.laps, opts.variant or None, opts.time_limit_s, opts.save)
    emit(result, opts.json, format_timing)
    return 0
