"""What the overtaking paper's Table III baselines share on the single-car race (the curriculum's stage 1: alone,
Eq. 1 with ``c_w`` 0.005, the 96-D ``overtaking`` observation, the paper's MLP of 2 x 256 ReLU units): the
options, the run folder, its records and the policy sidecar. Each learner (:mod:`.bc`, :mod:`.gail`,
:mod:`.online`, :mod:`.dreamer_train`) builds on it; :mod:`.baselines` sends each algorithm to its learner.

The run folder's files: docs/notes/overtaking.md, "baselines.py".
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vision_rl.config import flat_values
from vision_rl.envs.core import RacingConfig
from vision_rl.files import (
    CONTENT_KEY,
    clear_folder,
    content_damage,
    json_text,
    parse_json,
    sealed_record,
    write_json,
)
from vision_rl.overtaking.config import BUDGETS, OBSERVATION, TrainBaselineConfig, check_baseline_ranges
from vision_rl.overtaking.demos import OBS_DIM, Demos
from vision_rl.overtaking.dreamer import DreamerRecipe
from vision_rl.sim.track_library import load_track
from vision_rl.training.artifact import (
    MODEL_NAME,
    LoadedPolicy,
    PolicySpec,
    policy_fingerprint,
    racing_config_to_dict,
)
from vision_rl.training.presets import PRESETS, SACPreset

#: The Table III algorithms that learn online (all of them: :data:`~vision_rl.overtaking.config.ALGO_NAMES`).
ONLINE = ("gail", "td3", "sac", "dreamer")
#: The paper's network for every method (section IV-B): 2 hidden layers of 256 ReLU units.
HIDDEN_UNITS = (256, 256)
RUN_NAME = "baseline.json"
METRICS_NAME = "metrics.jsonl"
RUN_FORMAT = "vision_rl.baseline_run"
#: bc's default cap on gradient updates (it normally stops earlier, at convergence).
BC_DEFAULT_STEPS = 200_000


class BaselineError(ValueError):
    """A baseline run or policy that cannot be used as asked; the message says why."""


def default_out(cfg: TrainBaselineConfig) -> Path:
    track = cfg.racing.track.replace("random:", "random-")
    if track.endswith(".csv") or os.sep in track:
        track = Path(track).stem
    return Path("runs") / "baselines" / f"{cfg.algo}-{track}-{cfg.racing.car}-s{cfg.seed}"


def check_config(cfg: TrainBaselineConfig) -> None:
    """One clear line for a bad option, before anything is built or written."""
    check_baseline_ranges(flat_values(cfg))
    if cfg.algo in ONLINE:
        preset = resolve_recipe(cfg)
        if total_steps(cfg) <= preset.learning_starts:
            raise ValueError(
                f"--steps {total_steps(cfg)} is not above the {preset.learning_starts} random start "
                "steps (--learning-starts): it would make no update"
            )
        if preset.buffer_size < cfg.racing.n_groups:
            raise ValueError(
                f"--buffer-size {preset.buffer_size} holds less than one step of {cfg.racing.n_groups} cars"
            )


def resolve_recipe(cfg: TrainBaselineConfig) -> SACPreset:
    """The online recipe: the preset with the options' overrides, always the paper's 2 x 256 network."""
    base = PRESETS[cfg.sac.preset]
    return dataclasses.replace(
        base,
        hidden_units=HIDDEN_UNITS,
        learning_rate=cfg.sac.learning_rate or base.learning_rate,
        batch_size=cfg.sac.batch_size or base.batch_size,
        buffer_size=cfg.sac.buffer_size or base.buffer_size,
        learning_starts=base.learning_starts if cfg.sac.learning_starts < 0 else cfg.sac.learning_starts,
    )


def dreamer_recipe(cfg: TrainBaselineConfig) -> DreamerRecipe:
    """Dreamer's recipe with the options' overrides (sequences per update, the world model's step size)."""
    base = DreamerRecipe(hidden_units=HIDDEN_UNITS)
    return dataclasses.replace(
        base,
        batch_sequences=cfg.sac.batch_size or base.batch_sequences,
        sequence_steps=cfg.dreamer_sequence_steps,
        model_lr=cfg.sac.learning_rate or base.model_lr,
    )


def total_steps(cfg: TrainBaselineConfig) -> int:
    if cfg.steps:
        return cfg.steps
    return BC_DEFAULT_STEPS if cfg.algo == "bc" else BUDGETS[cfg.sac.preset].stage1_max_steps


def baseline_fingerprint(config: RacingConfig, algo: str) -> dict[str, Any]:
    """The policy fingerprint of :func:`~.artifact.policy_fingerprint` plus the algorithm."""
    return {**policy_fingerprint(config, OBSERVATION, OBS_DIM, None), "algo": algo}


def settings_of(cfg: TrainBaselineConfig, demos: Demos | None) -> dict[str, Any]:
    """What a run folder must keep when it is continued (``steps`` may grow)."""
    keep = {k: v for k, v in flat_values(cfg).items() if k not in ("steps", "out", "force", "device")}
    if cfg.algo in ONLINE:
        keep["recipe"] = json.loads(json.dumps(dataclasses.asdict(resolve_recipe(cfg))))
    if cfg.algo == "dreamer":
        keep["dreamer"] = json.loads(json.dumps(dataclasses.asdict(dreamer_recipe(cfg))))
    if demos is not None:
        keep["demos_sha256"] = demos.sha256
    return keep


def _read_json(path: Path) -> dict[str, Any]:
    """``baseline.json``, its content hash checked when it has one: one written before it was sealed (none) still
    reads, as its settings only guard a resume and the policies beside it are sealed themselves."""
    try:
        data = parse_json(path.read_text())
    except (OSError, ValueError) as exc:
        raise BaselineError(f"{path}: unreadable ({exc}); start over with --force") from None
    if not isinstance(data, dict) or data.get("format") != RUN_FORMAT:
        raise BaselineError(f"{path}: not a train-baseline record; start over with --force")
    damage = content_damage(data) if CONTENT_KEY in data else None
    if damage is not None:
        raise BaselineError(f"{path}: the run record {damage}; start over with --force")
    return data


def eval_figures(summary: dict[str, Any]) -> dict[str, Any]:
    """A periodic evaluation's protocol figures in metrics.jsonl: the best lap, the starts finished and why each
    start did not (None where it finished)."""
    return {
        "lap_time_s": summary["best_lap_time_s"],
        "finished": summary["n_finished"],
        "dnf_reasons": [seed["dnf_reason"] for seed in summary["seeds"]],
    }


def append_metrics(folder: Path, record: dict[str, Any]) -> None:
    with open(folder / METRICS_NAME, "a") as f:
        f.write(json_text(record) + "\n")


#: ``progress(phase, done, total, figures)``: bc reports epochs, the online algorithms environment steps.
Progress = Callable[[str, int, int, "dict[str, Any] | None"], None]


# ------------------------------------------------------------------------------------------------- the run folder


class RunFolder:
    """``baseline.json`` of a run: created fresh, or continued with the same settings."""

    def __init__(self, cfg: TrainBaselineConfig, demos: Demos | None) -> None:
        self.cfg = cfg
        self.out = Path(cfg.out) if cfg.out else default_out(cfg)
        self.settings = settings_of(cfg, demos)
        path = self.out / RUN_NAME
        if cfg.force and self.out.exists():
            clear_folder(self.out)  # the folder itself holds train_baseline's lock
        if path.is_file():
            record = _read_json(path)
            recorded = record.get("settings") or {}
            for key, want in self.settings.items():
                if recorded.get(key) != want:
                    raise BaselineError(
                        f"{path} was started with {key} = {recorded.get(key)!r}, not {want!r}: use "
                        "its settings, another --out, or --force to start over"
                    )
            self.record = record
        else:
            if self.out.exists() and any(self.out.iterdir()):
                raise BaselineError(f"{self.out} is not empty and holds no {RUN_NAME}: give another --out")
            self.record = {"format": RUN_FORMAT, "algo": cfg.algo, "settings": self.settings, "status": "new"}
            write_json(path, sealed_record(self.record))

    def update(self, **fields: Any) -> None:
        self.record.update(fields)
        write_json(self.out / RUN_NAME, sealed_record(self.record))


def policy_spec(
    cfg: TrainBaselineConfig,
    racing: RacingConfig,
    normalizer,
    fingerprint: dict[str, Any],
    sha256: str,
    recipe: dict[str, Any],
    num_timesteps: int,
    train_time_s: float,
    settings: dict[str, Any],
) -> PolicySpec:
    """The sidecar every learner writes beside its weights: the policy file's description, the run's settings."""
    return PolicySpec(
        observation=OBSERVATION,
        racing_config=racing_config_to_dict(racing),
        obs_normalizer=normalizer.to_dict(),
        fingerprint=fingerprint,
        weights_sha256=sha256,
        model=MODEL_NAME,
        preset=cfg.sac.preset,
        sac={**recipe, "hidden_units": list(HIDDEN_UNITS)},
        seed=cfg.seed,
        num_timesteps=int(num_timesteps),
        train_time_s=round(train_time_s, 2),
        train_config={**settings, "algo": cfg.algo},
    )


def baseline_algo(spec: PolicySpec) -> str:
    """The algorithm of a policy sidecar: its fingerprint's ``algo``; a policy without one is SAC (train-policy
    and train-overtaking write SAC policies)."""
    return str(spec.fingerprint.get("algo", "sac"))


def check_table_track(loaded: LoadedPolicy, track: str, car: str) -> None:
    """Refuse a policy trained on another track geometry or car than the table's."""
    fp = loaded.spec.fingerprint
    want = load_track(track).geometry_hash
    if fp.get("track_geometry_hash") != want or fp.get("car") != car:
        raise BaselineError(
            f"{loaded.spec_path}: trained on track {loaded.spec.racing_config.get('track')!r} "
            f"({str(fp.get('track_geometry_hash'))[:12]}...) with car {fp.get('car')!r}, not {track!r} "
            f"({want[:12]}...) with {car!r}"
        )
