"""`evaluate-overtaking`: settings A/B (the overtaking paper's Figs. 4-5) or, with --curves, its learning curves
(Fig. 3)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

from vision_rl.commands.choices import SETTINGS
from vision_rl.commands.options import comma_list, comma_paths
from vision_rl.commands.output import emit


@dataclass(frozen=True)
class EvaluateOvertakingOptions:
    """Overtaking policies and the built-in AI through setting A or B (five AI opponents 50 / 200 m apart): the
    paper's four metrics per run, mean, spread and best, bar charts; or, with --curves, the learning curves."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"setting": SETTINGS}

    setting: str = "A"
    """A (opponents 50 m apart) or B (200 m)."""
    runs: int = 10
    """Runs per driver (run k: opponents' skills and start jitter from seed + k)."""
    policy: str = ""
    """Comma-separated policies: stage folders of train-overtaking (RUN/stage2 is Agent 1, RUN/agent2-stage3, ...)."""
    names: str = ""
    """Comma-separated names of those policies in the table and charts (default: run/stage)."""
    reference: bool = True
    """Add the built-in AI driving the agent's car (the reference row)."""
    human: str = ""
    """Comma-separated setting.json files of `vision-rl play --setting` (a person's runs, the paper's reference)."""
    track: str = ""
    """Track (default: the policies'; expressway with no policy); a policy of another track is refused."""
    car: str = ""
    """Car (default: the policies'; tt_cup with no policy)."""
    seed: int = 0
    """First run's seed."""
    time_limit_s: float = 0.0
    """Time limit per run, s (0: 300 for A, 600 for B)."""
    lead_margin_m: float = 10.0
    """A run ends once the agent leads all five opponents by this much progress, m."""
    opponent_skill: tuple[float, float] = field(default=(0.80, 0.88), metadata={"metavar": ("LOW", "HIGH"), "max": 1.0})
    """Range the opponents' skills are drawn from (1: the limit profile; Table III's AI drives at 0.92)."""
    out: str = "runs/overtaking/eval"
    """Folder of the JSON and PNG files."""
    curves: str = ""
    """Comma-separated run folders (one per training seed): draw curriculum vs standard SAC learning curves instead."""
    curves_agent: str = "1"
    """Curriculum agent of the learning curves (1: stages 1-2, as the paper's Fig. 3)."""
    analysis: bool = False
    """With one --policy: the paper's Fig. 6 for its fastest run of --setting (cars overtaken against time with the
    collisions, the path of each pass, the driver view at each) beside the built-in AI's run with the same opponents."""
    analysis_run: int = field(default=-1, metadata={"min": -1})
    """With --analysis: the run to analyse instead of the fastest (0 to --runs - 1; -1: the fastest), e.g. one that
    did not overtake all five."""
    tiny: bool = False
    """2 runs of at most 20 s each (for a check in seconds)."""
    json: bool = False
    """Print the result as JSON."""


def format_setting(result: dict[str, Any]) -> list[str]:
    lines = [
        f"setting {result['setting']}: 5 opponents {result['separation_m']:g} m apart, {result['track_name']}, "
        f"{result['car']}, {result['runs']} runs, limit {result['time_limit_s']:g} s"
    ]
    lines.append(
        f"  {'driver':<28} {'all 5':>6} {'passed':>7} {'time s':>16} {'distance m':>18} {'car s':>12} {'wall s':>12}"
    )

    def cell(s: dict[str, Any], metric: str, digits: int = 1) -> str:
        m = s[metric]
        return f"{m['mean']:.{digits}f}+-{m['std']:.{digits}f} ({m['best']:.{digits}f})"

    for row in result["drivers"]:
        s = row["summary"]

        lines.append(
            f"  {row['name']:<28} {s['all_overtaken_runs']:>3}/{s['runs']:<2} {s['overtaken']['mean']:>7.1f} "
            f"{cell(s, 'travel_time_s'):>16} {cell(s, 'travel_distance_m', 0):>18} "
            f"{cell(s, 'car_contact_s'):>12} {cell(s, 'wall_contact_s'):>12}"
        )
    fastest = ", ".join(
        f"{row['name']} {row['summary']['fastest_all_five_s']:.1f} s"
        for row in result["drivers"]
        if row["summary"].get("fastest_all_five_s") is not None
    )
    lines.append("  (mean+-std (best) over the runs; best includes runs that ended early, stuck)")
    lines.append(f"  fastest run that passed all five: {fastest or 'none'}")
    lines.append(f"files: {result['files']['json']}, {result['files']['png']}")
    return lines


def format_curves(result: dict[str, Any]) -> list[str]:
    lines = []
    for label in ("curriculum", "standard"):
        data = result[label]
        lines.append(
            f"{label}: {data['seeds_with_data']} seeds, {len(data['x'])} points, up to "
            f"{data['x'][-1] if data['x'] else 0:.0f} ({min(data['n_seeds'] or [0])}-"
            f"{max(data['n_seeds'] or [0])} seeds a point)"
        )
    final = result.get("standard_final_return")
    if final is not None:
        partial = "" if result["complete"] else " (a seed is still training: the last point every seed reached)"
        lines.append(f"standard SAC's final mean return {final:.1f} at {result['standard_final_x']:.0f}{partial}")
    steps = result.get("curriculum_steps_to_standard_final")
    if steps is not None:
        lines.append(
            f"curriculum (every seed) reaches it at {steps:.0f} steps, standard SAC first at "
            f"{result['standard_steps_to_final']:.0f}: {100 * result['share_of_standard_steps']:.0f} % of its steps"
        )
    elif final is not None and result["axis"] == "num_timesteps":
        lines.append("curriculum (every seed) has not reached it")
    lines.append(f"files: {result['files']['json']}, {result['files']['png']}")
    return lines


def format_analysis(result: dict[str, Any]) -> list[str]:
    lines = [
        f"setting {result['setting']}, run {result['run']} of {result['runs']} (seed "
        f"{result['agent']['run']['seed']}): {result['run_choice']} of {result['agent']['name']}"
    ]
    for key in ("agent", "reference"):
        record = result[key]
        run = record["run"]
        passes = ", ".join(f"car {m['opponent']} at {m['time_s']:.1f} s" for m in record["moments"]) or "none"
        lines.append(
            f"  {record['name']:<28} {run['overtaken']}/5 in {run['travel_time_s']:.1f} s, car contact "
            f"{run['car_contact_s']:.1f} s, wall {run['wall_contact_s']:.1f} s; passes: {passes}"
        )
    files = result["files"]
    lines.append(
        "files: "
        + ", ".join(str(v) for k, v in files.items() if k != "frames")
        + (f", {len(files['frames'])} frames" if files.get("frames") else "")
    )
    return lines


def run_evaluate_overtaking(opts: EvaluateOvertakingOptions) -> int:
    from vision_rl.overtaking.settings import (
        check_setting,
        evaluate_overtaking,
        learning_curves,
        write_learning_curves,
        write_setting_outputs,
    )

    if opts.curves:
        result = learning_curves(comma_paths(opts.curves), opts.curves_agent)
        result["files"] = write_learning_curves(result, opts.out)
        emit(result, opts.json, format_curves)
        return 0
    check_setting(opts.setting)
    runs, limit = (2, opts.time_limit_s or 20.0) if opts.tiny else (opts.runs, opts.time_limit_s)
    if opts.analysis:
        return _analysis(opts, runs, limit)
    result = evaluate_overtaking(
        comma_paths(opts.policy),
        opts.setting,
        runs,
        opts.seed,
        limit,
        opts.lead_margin_m,
        opts.reference,
        comma_list(opts.names),
        opts.track,
        opts.car,
        humans=comma_paths(opts.human),
        opponent_skill=opts.opponent_skill,
    )
    result["files"] = write_setting_outputs(result, opts.out)
    emit(result, opts.json, format_setting)
    return 0


def _analysis(opts: EvaluateOvertakingOptions, runs: int, limit_s: float) -> int:
    from vision_rl.overtaking.curriculum import load_overtaking_policy
    from vision_rl.overtaking.settings import TRACE_SERIES, SettingError, analyse_overtaking, write_analysis_outputs
    from vision_rl.sim.track_library import load_track
    from vision_rl.sim.vehicle import get_preset

    policies = comma_paths(opts.policy)
    if len(policies) != 1:
        raise SettingError(f"--analysis takes one --policy, got {len(policies)}")
    policy = load_overtaking_policy(policies[0])
    track, car = load_track(policy.config.track), get_preset(policy.config.car)
    name = comma_list(opts.names)[0] if opts.names else policies[0]
    driver = policy.driver()
    try:
        result, trace = analyse_overtaking(
            driver,
            name,
            track,
            car,
            opts.setting,
            runs,
            opts.seed,
            limit_s,
            opts.lead_margin_m,
            None if opts.analysis_run < 0 else opts.analysis_run,
        )
    finally:
        if hasattr(driver, "close"):
            driver.close()
    result["files"] = write_analysis_outputs(
        result, trace, track, opts.out, car_length_m=car.length_m, car_width_m=car.width_m
    )
    # The series stay in the JSON file; the printed result keeps the runs, passes and contacts.
    for key in ("agent", "reference"):
        result[key] = {k: v for k, v in result[key].items() if k not in TRACE_SERIES}
    emit(result, opts.json, format_analysis)
    return 0
