"""`evaluate-ddpg`: a train-ddpg agent through the lap-time protocol."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from vision_rl.commands.choices import DDPG_VARIANTS
from vision_rl.commands.options import comma_list, comma_paths
from vision_rl.commands.output import emit


@dataclass(frozen=True)
class EvaluateDDPGOptions:
    """Time a train-ddpg agent with the lap-time protocol on its own track and car (two laps, the second scored,
    best and median over start seeds); stores evaluation.json beside the agent."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"variant": ("", *DDPG_VARIANTS)}

    agent: str = ""
    """A train-ddpg run folder or its ddpg.pt (required)."""
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
    video: str = ""
    """Also write an MP4 of the best start's run: the driver's view at the game screen's 470x280, a track map,
    speed and lap clock."""
    plot: str = ""
    """Also write a PNG of the best start's trajectory (speed along the track)."""
    reward_plot: str = ""
    """Also write the paper's figure (PNG, its numbers beside it as .json): reward against lap distance over
    --reward-laps laps of one episode from the start line."""
    reward_laps: int = 3
    """Laps of that figure (the paper: 3)."""
    reward_bin_m: float = 50.0
    """Lap distance per point of that figure, m."""
    json: bool = False
    """Print the result as JSON."""


def run_evaluate_ddpg(opts: EvaluateDDPGOptions) -> int:
    from vision_rl.commands.evaluate import format_timing
    from vision_rl.ddpg.train import evaluate_ddpg

    if opts.seeds < 1 or opts.laps < 1 or opts.time_limit_s < 0:
        raise ValueError("--seeds and --laps must be >= 1 and --time-limit-s >= 0")
    if opts.reward_laps < 1 or opts.reward_bin_m <= 0:
        raise ValueError("--reward-laps must be >= 1 and --reward-bin-m > 0")
    result = evaluate_ddpg(
        opts.agent,
        opts.seeds,
        opts.laps,
        opts.variant or None,
        opts.time_limit_s,
        opts.save,
        video=opts.video,
        plot=opts.plot,
    )
    if opts.reward_plot:
        from pathlib import Path

        from vision_rl.ddpg.agent import load_agent
        from vision_rl.ddpg.reward import lap_reward_profile, plot_lap_reward
        from vision_rl.files import write_json

        agent = load_agent(opts.agent, variant=opts.variant or None)
        profile = lap_reward_profile(agent.act, agent.env, opts.reward_laps, opts.reward_bin_m)
        result["reward_plot"] = str(plot_lap_reward(profile, opts.reward_plot, f"ddpg {agent.hyper.variant}"))
        result["reward_json"] = str(Path(opts.reward_plot).with_suffix(".json"))
        write_json(Path(result["reward_json"]), profile)
    emit(result, opts.json, format_timing)
    return 0


@dataclass(frozen=True)
class CompareDDPGOptions:
    """train-ddpg runs side by side at equal training time: distance per training episode against training minutes
    and episodes, and each run's first completed lap (PNG, and its numbers as JSON beside it)."""

    runs: str = ""
    """train-ddpg run folders, comma-separated (one track and car) (required)."""
    names: str = ""
    """Their names in the figure, comma-separated (default: variant and seed)."""
    bin_minutes: float = 5.0
    """Training minutes per point of the time axis."""
    out: str = "ddpg_compare.png"
    """The figure (PNG); the numbers go beside it as .json."""
    json: bool = False
    """Print the result as JSON."""


def format_compare(result: dict) -> list[str]:
    lines = [
        f"{result['track']} / {result['car']}: {len(result['runs'])} runs over the common "
        f"{result['common_minutes']:.1f} training minutes; distance per episode and reward per step, last third:"
    ]
    for r in result["runs"]:
        distance = "none" if r["mean_distance_last_m"] is None else f"{r['mean_distance_last_m']:.0f} m"
        lap = (
            "no lap"
            if r["first_lap_episode"] is None
            else (f"first lap in episode {r['first_lap_episode']} after {r['first_lap_minutes']:.1f} min")
        )
        cpu = "" if r["train_cpu_minutes"] is None else f", {r['train_cpu_minutes']:.1f} CPU minutes"
        reward = "" if r["reward_per_step_last"] is None else f", {r['reward_per_step_last']:+.1f} reward/step"
        lines.append(
            f"  {r['name']:<20} {distance:>8} (best {r['best_distance_m'] or 0:.0f} m){reward}, {r['episodes']} "
            f"episodes, {r['updates']} updates ({r['updates_per_s']:.2f}/s){cpu}; {lap}"
        )
    return [*lines, f"figure: {result['figure']}   numbers: {result['json']}"]


def run_compare_ddpg(opts: CompareDDPGOptions) -> int:
    from pathlib import Path

    from vision_rl.ddpg.compare import compare_runs, plot_comparison
    from vision_rl.files import sealed_record, write_json

    runs = comma_paths(opts.runs)
    names = comma_list(opts.names)
    result = compare_runs(runs, names, opts.bin_minutes)
    result["figure"] = str(plot_comparison(result, opts.out))
    result["json"] = str(Path(opts.out).with_suffix(".json"))
    write_json(result["json"], sealed_record(result))  # `vision-rl report` reads it: sealed, as every record is
    emit(result, opts.json, format_compare)
    return 0


@dataclass(frozen=True)
class DiagnoseDDPGOptions:
    """Whether trained DDPG agents' critics have diverged (mean Q beyond what any policy can earn or lose) and their
    actors' keys saturated, over episode starts of each agent's own task (JSON record)."""

    runs: str = ""
    """train-ddpg run folders (or their ddpg.pt), comma-separated (required)."""
    starts: int = field(default=64, metadata={"max": 4096})
    """Episode starts (the agent's own start rule) the critic and the actor are read at, each a car of one world."""
    seed: int = 0
    """Seed of the start points."""
    out: str = "ddpg_diagnosis.json"
    """The record (JSON): each run's Q against its bound and each key's pre-activation."""
    json: bool = False
    """Print the result as JSON."""


def format_diagnosis(result: dict) -> list[str]:
    lines = []
    for r in result["runs"]:
        saturated = ", ".join(f"{k} {v['saturated_share']:.0%}" for k, v in r["keys"].items())
        state = "DIVERGED" if r["diverged"] else "bounded"
        drive = r["protocol_start"]
        lines.append(
            f"  {r['name']:<20} critic {state}: mean Q {r['q_mean']:,.0f} (max {r['q_max']:,.0f}) against a bound "
            f"of +-{r['q_bound']:,.0f}; keys saturated: {saturated}; the protocol's {drive['seeds']} starts: laps "
            f"{drive['laps']}, wheels straight {drive['wheels_straight_share']:.0%}, full throttle "
            f"{drive['full_throttle_share']:.0%}, on the walls {drive['wall_contact_share']:.0%}"
        )
    return [*lines, f"record: {result['json']}"]


def run_diagnose_ddpg(opts: DiagnoseDDPGOptions) -> int:
    from pathlib import Path

    from vision_rl.ddpg.diagnose import diagnose_agent
    from vision_rl.files import sealed_record, write_json

    runs = comma_paths(opts.runs)
    if opts.starts < 1:
        raise ValueError(f"--starts must be >= 1, got {opts.starts}")
    result = {
        "runs": [{"name": Path(run).name, **diagnose_agent(run, opts.starts, opts.seed)} for run in runs],
        "json": opts.out,
    }
    write_json(opts.out, sealed_record(result))
    emit(result, opts.json, format_diagnosis)
    return 0
