"""`evaluate` (a policy through the lap-time protocol) and `vision-rl leaderboard` (the protocol's table)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar

from vision_rl.commands.choices import ENCODER_RUNTIMES
from vision_rl.commands.output import emit


def _lap(seconds: float | None) -> str:
    from vision_rl.evaluation.outputs import format_lap_time

    return format_lap_time(seconds)


def _hits(lap: dict[str, Any]) -> str:
    """ ", N hits, the fastest at V km/h" for a lap with wall hits (records of before the count have none)."""
    hits = lap.get("wall_hits", 0)
    return f", {hits} hits, the fastest at {lap['fastest_wall_hit_kmh']:.0f} km/h" if hits else ""


def format_timing(result: dict[str, Any]) -> list[str]:
    """Text lines of an evaluation record: the scored lap over seeds, then each seed's laps or its DNF."""
    driver = result["driver"]
    what = driver.get("observation") or f"skill {driver.get('skill', '?'):g}"
    protocol = result["protocol"]
    lines = [
        f"{result['name']} ({what}, {result['track_name']}, {result['car']}), protocol v{protocol['version']}: "
        f"best lap {protocol['scored_lap']} {_lap(result['best_lap_time_s'])}, median "
        f"{_lap(result['median_lap_time_s'])}, {result['n_finished']}/{result['n_seeds']} seeds finished"
        + ("" if result["best_lap_time_s"] is None else (", clean" if result["clean"] else ", not clean")),
    ]
    for s in result["seeds"]:
        laps = "; ".join(
            f"{_lap(lap['lap_time_s'])} (wall {lap['wall_contact_s']:.1f} s{_hits(lap)}, off track "
            f"{lap['off_track_s']:.1f} s, {lap['avg_speed_kmh']:.1f} km/h)"
            for lap in s["laps"]
        )
        status = "" if s["dnf_reason"] is None else f"; DNF: {s['dnf_reason']}"
        lines.append(f"  seed {s['seed']}: {laps or 'no lap'}; {s['distance_m']:.0f} m driven{status}")
    sections = result.get("sections")
    if sections is not None and sections["rows"] is None:
        lines.append("sections: no seed finished its scored lap")
    elif sections is not None:
        ref = sections["reference"]
        rows = sorted(sections["rows"], key=lambda r: -r["loss_s"])[:TOP_SECTIONS]
        lines.append(
            f"where the best lap loses most against the built-in AI at skill {ref['skill']:g} "
            f"({_lap(ref['lap_time_s'])}), {sections['section_m']:g} m sections:"
        )
        lines.append("  from m    lap s  AI s   lost s  min km/h (AI)  wall s")
        for r in rows:
            lines.append(
                f"  {r['start_m']:6.0f}  {r['time_s']:6.2f}  {r['reference_time_s']:5.2f}  "
                f"{r['loss_s']:+6.2f}  {r['min_speed_kmh']:5.0f} ({r['reference_min_speed_kmh']:3.0f})  "
                f"{r['wall_contact_s']:6.1f}"
            )
        lap, ai = sections["controls"]["lap"], sections["controls"]["reference"]
        if lap["steps"] and ai["steps"]:
            lines.append(
                f"above {lap['fast_above_kmh']:.0f} km/h (the best lap / the AI's): full throttle "
                f"{lap['full_throttle_share']:.0%} / {ai['full_throttle_share']:.0%} of the steps, the "
                f"wheel at the end of its usable angle {lap['range_end_share']:.0%} / "
                f"{ai['range_end_share']:.0%}, changing side {lap['steer_sign_change_share']:.0%} / "
                f"{ai['steer_sign_change_share']:.0%}"
            )
    errors = result.get("encoder_error")
    if errors is not None:
        policy, ai = errors["policy"], errors["built_in_ai"]
        subsets = ("all", "near_wall", "wall_contact")
        lines.append(
            f"encoder error (mean absolute), the best lap / the built-in AI's at skill {ai['skill']:g}: "
            + ", ".join(f"{k}: {policy[k]['frames']} / {ai[k]['frames']} frames" for k in subsets)
        )
        for name, unit in policy["units"].items():
            cells = (
                " / ".join("-" if d[k][name] is None else f"{d[k][name]:.3f}" for d in (policy, ai)) for k in subsets
            )
            lines.append(f"  {name} ({unit}): " + ", ".join(f"{k} {c}" for k, c in zip(subsets, cells, strict=True)))
    for key in ("plot", "video", "trace", "evaluation_json", "reward_plot"):
        if result.get(key):
            lines.append(f"{key}: {result[key]}")
    return lines


@dataclass(frozen=True)
class EvaluateOptions:
    """Evaluate a policy with the lap-time protocol: two consecutive laps from a rolling start, lap 2 scored, best
    and median over start seeds; stores evaluation.json beside the policy for the leaderboard."""

    option_choices: ClassVar[dict[str, tuple[str, ...]]] = {"encoder_runtime": ENCODER_RUNTIMES}

    policy: str = ""
    """Policy: a train-policy run folder or its policy.pt; or, with ``env_id``, a Stable-Baselines3 zip (PPO, A2C, SAC,
    TD3, DDPG with an MLP policy), read from its tensors, never its pickled parts."""
    python: str = ""
    """An agent trained elsewhere, module:function or path/to/file.py:function (with ``env_id``): the function itself
    maps a batch of the environment's observations to a batch of its actions (vision_rl.evaluate's predict; build one
    at import with predict = make_agent()). Imports the module, running its code."""
    env_id: str = ""
    """With ``python`` or an SB3 zip: the registered environment the agent was trained on (vision_rl/TimeTrial-v1...):
    what it observes and how it acts."""
    track: str = ""
    """With ``env_id``: the environment's track, built-in name, random:SEED or CSV path (empty: its default)."""
    car: str = ""
    """With ``env_id``: the environment's car preset (empty: its default)."""
    env_kwargs: str = ""
    """With ``env_id``: more arguments of the environment as a JSON object, as gymnasium.make takes them
    ('{"observation": "vision"}'; vision's encoder is ``encoder``)."""
    runs: str = "runs"
    """With ``env_id``: the record goes to RUNS/NAME/evaluation.json, where leaderboard finds it."""
    laps: int = 2
    """Consecutive laps; the last one is the score (the papers: 2)."""
    seeds: int = 3
    """Start seeds (small start jitter each), driven at once."""
    seed: int = 0
    """First seed."""
    encoder: str = ""
    """Vision: encoder ckpt.pt (refused unless the one it was trained with)."""
    time_limit_s: float = 0.0
    """Stop a run after this long, s (0: 3 x the limit lap time per lap)."""
    video: str = ""
    """Write the best seed's driver's view with a track map (mp4)."""
    plot: str = ""
    """Write the best seed's trajectory coloured by speed (png)."""
    trace: str = ""
    """Write every seed's run, one row per 0.1 s step up to its finish or DNF (csv): pose, arc length and lateral
    offset, speed, heading against the track's, steering, pedal, wall contact; how a start got stuck."""
    name: str = ""
    """Name on the leaderboard (default: the run folder's name; an outside agent's module:function or zip name)."""
    device: str = "auto"
    """Torch device of the policy and encoder: auto (cuda when torch sees a GPU, else cpu), cpu or cuda."""
    write: bool = True
    """Store evaluation.json beside the policy for the leaderboard."""
    encoder_runtime: str = "auto"
    """Vision: auto (ONNX Runtime on a CPU when installed: the encoder 3-6x faster here), torch or onnxruntime."""
    sections_m: float = 0.0
    """Cut the best scored lap into sections this long and compare it with the built-in AI's, and say how each drives
    where a steering-rate step exceeds the usable angle: full throttle, the wheel at its range's ends (0: off)."""
    reference_skill: float = field(default=1.0, metadata={"max": 1.0})
    """With --sections-m: the built-in AI's skill on the same starts (1.0: its fastest)."""
    encoder_error: bool = False
    """Vision: the encoder's error on the 27 targets along the best lap, beside the built-in AI's lap (default
    skill, same start): how well Phase 1 sees where the policy drives."""
    json: bool = False
    """Print the result as JSON."""


#: Sections printed by ``evaluate --sections-m`` (the JSON holds them all).
TOP_SECTIONS = 8


def run_evaluate(opts: EvaluateOptions) -> int:
    from vision_rl.training.evaluate import evaluate_policy
    from vision_rl.training.sac import torch_device

    opts = replace(opts, device=torch_device(opts.device))

    if opts.python or opts.env_id:
        emit(_evaluate_outside(opts), opts.json, format_timing)
        return 0
    if not opts.policy:
        raise ValueError(
            "evaluate needs --policy (a train-policy run folder or its policy.pt) or --python with --env-id"
        )
    if opts.track or opts.car or opts.env_kwargs:
        raise ValueError("--track, --car and --env-kwargs describe an outside agent's environment: give --env-id")
    if opts.policy.endswith(".zip") and not (Path(opts.policy).parent / "policy.json").is_file():
        raise ValueError(
            f"{opts.policy} is a Stable-Baselines3 zip: give --env-id, the environment it was trained on "
            "(it is read from its tensors, never its pickled parts)"
        )
    result = evaluate_policy(
        opts.policy,
        laps=opts.laps,
        seeds=opts.seeds,
        seed=opts.seed,
        encoder=opts.encoder,
        time_limit_s=opts.time_limit_s,
        video=opts.video,
        plot=opts.plot,
        name=opts.name,
        device=opts.device,
        write=opts.write,
        encoder_runtime=opts.encoder_runtime,
        sections_m=opts.sections_m,
        reference_skill=opts.reference_skill,
        encoder_error=opts.encoder_error,
        trace=opts.trace,
    )
    emit(result, opts.json, format_timing)
    return 0


def _evaluate_outside(opts: EvaluateOptions) -> dict[str, Any]:
    """``--python module:function`` or ``--policy agent.zip``, with ``--env-id``, through :func:`vision_rl.evaluate`."""
    from vision_rl.training.evaluate import ProtocolRun
    from vision_rl.training.outside import evaluate_agent, load_python_agent, read_sb3_actor, sb3_zip_source

    if not opts.env_id:
        raise ValueError("--python needs --env-id: the registered environment the agent was trained on")
    if bool(opts.python) == bool(opts.policy):
        raise ValueError("--env-id times one outside agent: give --python module:function or --policy agent.zip")
    if opts.policy and not opts.policy.endswith(".zip"):
        raise ValueError(
            f"--policy {opts.policy} with --env-id: give a Stable-Baselines3 zip (a train-policy run "
            "carries its environment: drop --env-id)"
        )
    env_kwargs = _env_kwargs(opts)
    if opts.python:
        agent, source = load_python_agent(opts.python), {"python": opts.python}
        name = opts.name or opts.python.replace(".py:", ":").rsplit("/", 1)[-1]
    else:
        agent = read_sb3_actor(opts.policy)
        source, name = sb3_zip_source(agent), opts.name or Path(opts.policy).stem
    source["remeasure"] = _remeasure_line(opts, name)
    run = ProtocolRun(
        opts.laps,
        opts.seeds,
        opts.seed,
        opts.time_limit_s,
        opts.video,
        opts.plot,
        opts.trace,
        opts.sections_m,
        opts.reference_skill,
        opts.encoder_error,
    )
    return evaluate_agent(
        agent,
        opts.env_id,
        name,
        env_kwargs,
        run,
        opts.runs,
        opts.write,
        opts.encoder or None,
        opts.device,
        opts.encoder_runtime,
        source,
    )


def _env_kwargs(opts: EvaluateOptions) -> dict[str, Any]:
    """--env-kwargs (a JSON object) with --track and --car."""
    import json

    try:
        kwargs = json.loads(opts.env_kwargs) if opts.env_kwargs else {}
    except ValueError as exc:
        raise ValueError(f"--env-kwargs is not JSON: {exc}") from None
    if not isinstance(kwargs, dict):
        raise ValueError(f"--env-kwargs must be a JSON object of the environment's arguments, got {opts.env_kwargs}")
    if "encoder" in kwargs:
        raise ValueError("give vision's encoder as --encoder, not in --env-kwargs")
    kwargs.update({k: v for k, v in (("track", opts.track), ("car", opts.car)) if v})
    return kwargs


def _remeasure_line(opts: EvaluateOptions, name: str) -> str:
    """The command line that times this outside agent again."""
    import shlex

    agent = f"--python {shlex.quote(opts.python)}" if opts.python else f"--policy {shlex.quote(opts.policy)}"
    extra = [
        (flag, v)
        for flag, v in (
            ("--track", opts.track),
            ("--car", opts.car),
            ("--env-kwargs", opts.env_kwargs),
            ("--encoder", opts.encoder),
            ("--runs", opts.runs),
        )
        if v
    ]
    return " ".join(
        [f"vision-rl evaluate {agent} --env-id {shlex.quote(opts.env_id)} --name {shlex.quote(name)}"]
        + [f"{flag} {shlex.quote(v)}" for flag, v in extra]
    )


def format_leaderboard(result: dict[str, Any]) -> list[str]:
    """The table as text; refused evaluations after it."""

    def pct(v: float | None) -> str:
        return "-" if v is None else f"{v:+.2f}"

    rows = result["rows"]
    width = max(26, *(len(r["name"]) for r in rows))
    lines = [
        f"{result['track']} / {result['car']} (lap-time protocol v{result['protocol_version']}; "
        f"physical limit {_lap(result['limit_lap_time_s'])})",
        f"{'name':<{width}}  {'lap':>9}  {'vs limit %':>10}  {'vs AI %':>8}  {'median':>9}  {'finished':>8}  clean",
    ]
    for r in rows:
        clean = "-" if r["lap_time_s"] is None else ("yes" if r["clean"] else "no")
        # An experiment's row has no median over starts (its seeds' mean is on the next line), not a DNF.
        median = "-" if "experiment_json" in r else _lap(r["median_lap_time_s"])
        lines.append(
            f"{r['name']:<{width}}  {_lap(r['lap_time_s']):>9}  {pct(r['gap_to_limit_pct']):>10}  "
            f"{pct(r['gap_to_ai_pct']):>8}  {median:>9}  {r['finished']:>8}  {clean}"
        )
        if r.get("lap_time_mean_s") is not None:  # an experiment: the best seed above, the seeds' spread here
            std = r["lap_time_std_s"]
            lines.append(
                f"{'':<{width}}  mean over seeds {_lap(r['lap_time_mean_s'])}"
                + ("" if std is None else f" +- {std:.2f} s")
            )
    lines += [f"refused: {why}" for why in result.get("refused", [])]
    return lines


@dataclass(frozen=True)
class LeaderboardOptions:
    """Lap-time table of one track and car (Table 1 of the vision paper): the built-in AI measured now and every
    evaluated policy, all through the lap-time protocol, with gaps to the physical limit and to the AI."""

    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "hatchback"
    """Car preset."""
    runs: str = "runs"
    """Folder searched for evaluation.json files."""
    json: bool = False
    """Print the table as JSON."""


def run_leaderboard(opts: LeaderboardOptions) -> int:
    from vision_rl.evaluation.leaderboard import leaderboard

    emit(leaderboard(opts.track, opts.car, opts.runs), opts.json, format_leaderboard)
    return 0
