"""`vision-rl dreamer-model`: a Dreamer run's world-model prediction error on held-out laps, beside holding the last
observation (:mod:`vision_rl.overtaking.dreamer_model_error`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from vision_rl.commands.output import emit, number_text

#: Bytes a start point holds per step of its context and horizon: its observation, action, reward, the encoder's
#: embedding and the squared errors, float32, with room for the recurrent states.
BYTES_PER_START_STEP = 2000


def parse_horizons(text: str) -> tuple[int, ...]:
    """``"1,5,10"`` -> (1, 5, 10); a word or an empty list is refused in one line."""
    from vision_rl.commands.options import comma_list

    try:
        horizons = tuple(comma_list(text, int))
    except ValueError:
        raise ValueError(f"--horizons takes whole numbers of steps separated by commas, got {text!r}") from None
    if not horizons:
        raise ValueError("--horizons names no horizon")
    return horizons


@dataclass(frozen=True)
class DreamerModelOptions:
    """Measure a Dreamer run's world model on held-out laps (record-demos of the built-in AI): from each start point
    it filters its posterior over the context with the true observations and actions, then imagines open-loop with
    the true actions; per horizon, the RMSE of the predicted observation (normalised units, per group of entries)
    and reward, beside a baseline holding the last observation. Writes a sealed JSON record and a PNG."""

    @staticmethod
    def check_options(options: Mapping[str, Any]) -> None:
        from vision_rl.budget import require_memory
        from vision_rl.overtaking.dreamer_model_error import check_horizons

        horizons = parse_horizons(options["horizons"])
        check_horizons(horizons, options["context_steps"])
        steps = options["context_steps"] + max(horizons)
        require_memory(
            f"--starts {options['starts']} of {steps} steps (--context-steps plus the longest horizon)",
            float(options["starts"]) * steps * BYTES_PER_START_STEP,
        )

    run: str = ""
    """A train-baseline --algo dreamer run folder (required)."""
    laps: str = ""
    """Held-out laps: a record-demos file of the run's track and car, not trained on (required)."""
    context_steps: int = 20
    """Steps the posterior is filtered over before each open-loop prediction (2 s at 10 Hz)."""
    horizons: str = "1,5,10,25,50"
    """Horizons reported, control steps, separated by commas (the curve covers every step to the longest)."""
    starts: int = 1000
    """Start points drawn at random among those the laps hold (all of them when fewer)."""
    seed: int = 0
    """Seed of the draw of start points."""
    out: str = ""
    """The JSON record (its PNG beside it, .png); empty: model_error.json in the run folder."""
    json: bool = False
    """Print the result as JSON."""


def format_dreamer_model(result: dict[str, Any]) -> list[str]:
    settings = result["settings"]
    lines = [
        f"world model of {result['made_from']['policy']} ({result['num_timesteps']} steps) on "
        f"{result['made_from']['laps']}: {result['n_starts']} start points of {result['n_start_points_available']}, "
        f"context {settings['context_steps']} steps",
        "  the context's last observation reconstructed: RMSE "
        + number_text(result["reconstruction"]["observation_rmse"], 3),
        f"  {'horizon':>12} | {'obs RMSE':>9} {'hold last':>9} {'ratio':>6} | {'reward RMSE':>11} {'hold last':>9}"
        f" {'bias':>7} {'true':>7}",
    ]
    for row in result["horizons"]:
        model, hold = row["model"], row["hold_last"]
        obs_model, obs_hold = (number_text(x["observation_rmse"], 3) for x in (model, hold))
        reward_model, reward_hold = (number_text(x["reward_rmse"], 3) for x in (model, hold))
        ratio = number_text(row["observation_rmse_ratio_to_hold_last"], 2)
        bias, true = number_text(model["reward_bias"], 3), number_text(row["true_reward_mean"], 3)
        lines.append(
            f"  {row['horizon_steps']:>4} ({row['horizon_s']:>4.1f} s) | {obs_model:>9} {obs_hold:>9} {ratio:>6} | "
            f"{reward_model:>11} {reward_hold:>9} {bias:>7} {true:>7}"
        )
    longest = result["horizons"][-1]
    groups = ", ".join(
        f"{name} {number_text(value, 2)}/{number_text(longest['hold_last']['groups'][name], 2)}"
        for name, value in longest["model"]["groups"].items()
    )
    lines.append(f"  per group at {longest['horizon_steps']} steps (model/hold last): {groups}")
    lines.append(f"wrote {result['files']['json']} and {result['files']['png']}")
    return lines


def run_dreamer_model(opts: DreamerModelOptions) -> int:
    from vision_rl.overtaking.dreamer_model_error import (
        default_out,
        load_dreamer_run,
        load_laps_for,
        model_error,
        write_model_error,
    )

    run = load_dreamer_run(opts.run)
    laps = load_laps_for(opts.laps, run)
    result = model_error(
        run,
        laps,
        context_steps=opts.context_steps,
        horizons=parse_horizons(opts.horizons),
        starts=opts.starts,
        seed=opts.seed,
    )
    files = write_model_error(result, opts.out or default_out(run))
    emit({**result, "files": files}, opts.json, format_dreamer_model)
    return 0
