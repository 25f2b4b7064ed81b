"""`tune`: an Optuna search over train-policy's recipe. Each trial trains one policy from a base recipe with some
options drawn from :data:`~vision_rl.phase2_rl.config.SEARCH_SPACE` (one training seed per trial: a winner is
confirmed by ``experiment``), and its score is the lap-time protocol's; the study resumes from ``OUT/study.db``.

The score, the pruning and resuming: docs/notes/phase2_rl.md.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vision_rl.config import flat_values, replace_flat
from vision_rl.files import write_json
from vision_rl.phase2_rl.config import SEARCH_SPACE, TrainPolicyConfig
from vision_rl.phase2_rl.train import train_policy
from vision_rl.training.evaluate import evaluate_policy
from vision_rl.training.sac import Progress

STUDY_DB = "study.db"
STUDY_JSON = "study.json"
#: A start that did not finish scores this many physical-limit laps (a policy's finished laps here are 1.03-1.2).
DNF_LAP_FACTOR = 2.0
#: Optuna's heartbeat, s: a trial whose process has not beaten for ``HEARTBEAT_GRACE_S`` is failed and redrawn.
HEARTBEAT_S = 60
HEARTBEAT_GRACE_S = 300


@dataclass(frozen=True)
class TuneConfig:
    """How the search runs (the recipe it starts from is a TrainPolicyConfig)."""

    trials: int = 20
    """Complete or pruned trials the study holds when the command ends."""
    space: tuple[str, ...] = tuple(SEARCH_SPACE)
    """Names of the searched options (the base recipe's value for the others)."""
    eval_starts: int = 3
    """Starts of the protocol that scores a trained policy."""
    wall_weight: float = 0.0
    """Seconds of score per second of wall contact in the scored laps (0: lap time alone)."""
    prune_after_steps: int = 100_000
    """Steps before a trial may be pruned (0: never prune)."""
    sampler_seed: int = 0
    """Seed of Optuna's TPE sampler."""


class TuneError(ValueError):
    """A search that cannot run as asked; the message says why."""


def score(
    scored_laps_s: Sequence[float | None],
    wall_contact_s: Sequence[float],
    limit_lap_time_s: float,
    wall_weight: float = 0.0,
) -> float:
    """The module's score of one protocol run: per start its scored lap (None: did not finish) and that lap's wall
    contact (s)."""
    if not scored_laps_s:
        raise TuneError("no protocol starts to score")
    laps = [DNF_LAP_FACTOR * limit_lap_time_s if lap is None else lap for lap in scored_laps_s]
    return float(sum(laps) / len(laps) + wall_weight * sum(wall_contact_s) / len(laps))


def _evaluation_score(evaluation: dict[str, Any], wall_weight: float) -> float:
    """:func:`score` of a protocol summary (an evaluation.json, or train-policy's periodic record, which carries
    the same per-start figures)."""
    if "seeds" in evaluation:
        starts = evaluation["seeds"]
        laps = [s["lap_time_s"] for s in starts]
        wall = [s["laps"][-1]["wall_contact_s"] if s["finished"] else 0.0 for s in starts]
    else:
        laps, wall = evaluation["scored_lap_times_s"], evaluation["scored_wall_contact_s"]
    return score(laps, wall, evaluation["limit_lap_time_s"], wall_weight)


def check_tune(base: TrainPolicyConfig, tune: TuneConfig) -> None:
    """One clear line for a search that cannot run, before anything is written."""
    unknown = [name for name in tune.space if name not in SEARCH_SPACE]
    if unknown or not tune.space:
        raise TuneError(f"--space: {', '.join(unknown) or 'empty'}: choose from {', '.join(SEARCH_SPACE)}")
    if len(set(tune.space)) != len(tune.space):
        raise TuneError(f"--space {','.join(tune.space)}: an option is repeated")
    if tune.trials < 1 or tune.eval_starts < 1 or tune.wall_weight < 0 or tune.prune_after_steps < 0:
        raise TuneError("--trials and --eval-starts must be >= 1, --wall-weight and --prune-after-steps >= 0")
    if base.resume or base.samplers.workers is not None:
        raise TuneError("tune trains each trial from scratch in this process: leave out --resume and --workers")


def _suggest(trial: Any, name: str) -> Any:
    param = SEARCH_SPACE[name]
    if param.kind == "log":
        return trial.suggest_float(name, *param.values, log=True)
    return trial.suggest_categorical(name, list(param.values))


def recipe_flags(params: dict[str, Any]) -> str:
    """Command-line flags of a trial's drawn options, for train-policy or experiment."""
    return " ".join(f"--{k.replace('_', '-')} {v}" for k, v in sorted(params.items()))


def _study_record(base: TrainPolicyConfig, tune: TuneConfig) -> dict[str, Any]:
    recipe = {k: v for k, v in flat_values(base).items() if k not in ("out", "resume", "force", "device")}
    return {
        "base_recipe": recipe,
        "space": list(tune.space),
        "eval_starts": tune.eval_starts,
        "wall_weight": tune.wall_weight,
        "score": f"mean scored lap over {tune.eval_starts} starts (s), a start that did not finish "
        f"{DNF_LAP_FACTOR:g} x the limit's lap, + {tune.wall_weight:g} s per s of wall contact",
    }


def run_tune(
    base: TrainPolicyConfig,
    tune: TuneConfig,
    out: str | os.PathLike[str],
    trial_started: Callable[[int, dict[str, Any]], None] | None = None,
    train_progress: Progress | None = None,
) -> dict[str, Any]:
    """Run the study in ``out`` until it holds ``tune.trials`` complete or pruned trials; returns its record (also
    written to ``out/study.json``). ``trial_started(number, params)`` is called as each trial starts. A
    KeyboardInterrupt stops the study after saving the running trial's run folder."""
    try:
        import optuna
    except ModuleNotFoundError:
        raise TuneError("tune needs Optuna: pip install 'vision-rl[tune]'") from None

    check_tune(base, tune)
    root = Path(out)
    record = _study_record(base, tune)
    path = root / STUDY_JSON
    if path.is_file():
        previous = json.loads(path.read_text())
        for key in ("base_recipe", "space", "eval_starts", "wall_weight"):
            if previous.get(key) != record[key]:
                raise TuneError(f"{root} holds a study with another {key.replace('_', ' ')}: use another --out")
    write_json(path, record)
    study = _open_study(optuna, root, tune)
    objective = _Objective(optuna, study, base, tune, root, trial_started, train_progress)
    done = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    study.optimize(objective, callbacks=[optuna.study.MaxTrialsCallback(tune.trials, states=done)])
    result = {**record, **summarise_study(study), "interrupted": objective.stopped, "study_db": str(root / STUDY_DB)}
    write_json(path, result)
    return {**result, "study_json": str(path)}


def _open_study(optuna: Any, root: Path, tune: TuneConfig) -> Any:
    """The study of ``root/study.db``, created or loaded: TPE seeded by ``tune.sampler_seed``, median pruning."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)  # library code prints nothing
    with warnings.catch_warnings():  # the heartbeat is "experimental" in Optuna 4-5; it is what resume relies on
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        url = f"sqlite:///{(root / STUDY_DB).resolve()}"
        storage = optuna.storages.RDBStorage(url, heartbeat_interval=HEARTBEAT_S, grace_period=HEARTBEAT_GRACE_S)
    pruner = (
        optuna.pruners.MedianPruner(n_startup_trials=3, n_warmup_steps=tune.prune_after_steps)
        if tune.prune_after_steps > 0
        else optuna.pruners.NopPruner()
    )
    return optuna.create_study(
        storage=storage,
        study_name="tune",
        direction="minimize",
        load_if_exists=True,
        sampler=optuna.samplers.TPESampler(seed=tune.sampler_seed),
        pruner=pruner,
    )


class _Objective:
    """One trial: train the drawn recipe (pruned on its periodic evaluations), then score it by the protocol.
    ``stopped`` turns true when a Ctrl-C ended a trial, which also stops the study."""

    def __init__(self, optuna, study, base, tune, root, trial_started, train_progress) -> None:
        self.optuna, self.study, self.base, self.tune, self.root = optuna, study, base, tune, root
        self.trial_started, self.train_progress = trial_started, train_progress
        self.stopped = False

    def __call__(self, trial: Any) -> float:
        params = {name: _suggest(trial, name) for name in self.tune.space}
        if self.trial_started is not None:
            self.trial_started(trial.number, params)
        pruned = []

        def progress(steps: int, total: int, last_eval: dict[str, Any] | None) -> None:
            if self.train_progress is not None:
                self.train_progress(steps, total, last_eval)
            if last_eval is None or last_eval["num_timesteps"] != steps:
                return
            trial.report(_evaluation_score(last_eval, self.tune.wall_weight), steps)
            if trial.should_prune():
                pruned.append(steps)
                raise KeyboardInterrupt  # train_policy saves the run folder and returns

        run = self.root / f"trial-{trial.number}"
        cfg = replace_flat(self.base, **params, out=str(run), resume=False, force=True, save_buffer=False)
        result = train_policy(cfg, progress)
        if pruned:
            raise self.optuna.TrialPruned
        if result["interrupted"]:
            self.stopped = True
            self.study.stop()
            raise self.optuna.TrialPruned  # a Ctrl-C: the trial did not run its course
        name = f"{self.root.name}/trial-{trial.number}"
        evaluation = evaluate_policy(run, seeds=self.tune.eval_starts, name=name, encoder=self.base.encoder)
        trial.set_user_attr("lap_time_s", evaluation["median_lap_time_s"])
        trial.set_user_attr("finished", f"{evaluation['n_finished']}/{evaluation['n_seeds']}")
        trial.set_user_attr("train_time_s", result["train_time_s"])
        return _evaluation_score(evaluation, self.tune.wall_weight)


def summarise_study(study: Any) -> dict[str, Any]:
    """Every trial (number, state, drawn options, score, protocol lap, steps it reached) and the best complete one."""
    trials = []
    for t in study.trials:
        last_step = max(t.intermediate_values) if t.intermediate_values else None
        trials.append(
            {
                "number": t.number,
                "state": t.state.name,
                "params": t.params,
                "score_s": None if t.value is None or not math.isfinite(t.value) else t.value,
                "last_reported_step": last_step,
                **t.user_attrs,
            }
        )
    complete = [t for t in trials if t["state"] == "COMPLETE" and t["score_s"] is not None]
    best = min(complete, key=lambda t: t["score_s"]) if complete else None
    return {"trials": trials, "best": best, "best_flags": recipe_flags(best["params"]) if best else None}


__all__ = [
    "DNF_LAP_FACTOR",
    "TuneConfig",
    "TuneError",
    "check_tune",
    "recipe_flags",
    "run_tune",
    "score",
    "summarise_study",
]
