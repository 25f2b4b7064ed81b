"""`play`: a person drives the protocol's laps; the lap time becomes a leaderboard row "human (alias)" and the
drive a demonstrations file the imitation baselines read (:mod:`vision_rl.overtaking.demos`)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

from vision_rl.envs.observer import Observer
from vision_rl.evaluation.human import HumanDriver, HumanQuit, check_display
from vision_rl.evaluation.leaderboard import evaluation_record
from vision_rl.evaluation.protocol import time_laps
from vision_rl.files import write_json
from vision_rl.overtaking.config import ALIAS_PATTERN, OBSERVATION, PlayConfig
from vision_rl.overtaking.demos import demo_fingerprint, environment_normalizer, write_demos
from vision_rl.overtaking.settings import check_setting, run_setting, summarise_runs
from vision_rl.sim.track_library import load_track


def check_play_config(cfg: PlayConfig) -> None:
    if not ALIAS_PATTERN.fullmatch(cfg.name):
        raise ValueError(f"--name {cfg.name!r}: give an alias of letters, digits, _ . - (up to 32 characters)")
    if cfg.laps < 1:
        raise ValueError(f"--laps must be >= 1, got {cfg.laps}")
    if cfg.time_limit_s < 0:
        raise ValueError(f"--time-limit-s must be >= 0, got {cfg.time_limit_s}")
    if min(cfg.window_hw_px) < 64:
        raise ValueError(f"--window-hw-px {cfg.window_hw_px}: at least 64 x 64")
    if cfg.setting:
        check_setting(cfg.setting)
        if cfg.setting_runs < 1:
            raise ValueError(f"--setting-runs must be >= 1, got {cfg.setting_runs}")


def play(cfg: PlayConfig, events=None) -> dict[str, Any]:
    """Run the protocol with a :class:`HumanDriver`; write the evaluation record and the demonstrations. A run
    ended by the player keeps its demonstrations and writes no row. ``events``: a scripted input source."""
    check_play_config(cfg)
    check_display()
    if cfg.setting:
        return play_setting(cfg, events)
    track = load_track(cfg.track)
    normalizer = environment_normalizer(cfg.track, cfg.car)
    driver = HumanDriver(
        cfg.camera,
        cfg.window_hw_px,
        cfg.input,
        cfg.realtime,
        lambda world: Observer(OBSERVATION, world.track, world.car, world.model.groups, normalizer),
        events,
    )
    out = Path(cfg.runs) / "human" / f"{cfg.name}-{track.name}-{cfg.car}"
    result: dict[str, Any] = {"name": f"human ({cfg.name})", "settings": asdict(cfg)}
    try:
        timing = time_laps(driver, track, cfg.car, [cfg.seed], cfg.laps, cfg.time_limit_s)
        record = evaluation_record(timing, {**driver.identity, "alias": cfg.name}, result["name"])
    except HumanQuit:
        record = None
    finally:
        driver.close()
    out.mkdir(parents=True, exist_ok=True)
    arrays = driver.recording.arrays()
    demos = Path(cfg.demos) if cfg.demos else out / "demos.npz"
    if len(arrays["actions"]):
        meta = {
            "fingerprint": demo_fingerprint(cfg.track, cfg.car, normalizer),
            "track": cfg.track,
            "track_name": track.name,
            "demonstrator": {**driver.identity, "alias": cfg.name},
            "settings": asdict(cfg),
            "normalizer": normalizer.to_dict(),
            "n_transitions": len(arrays["actions"]),
            "n_episodes": 1,
            "mean_reward": float(arrays["rewards"].mean()),
        }
        write_demos(demos, arrays, meta)
        result["demos"] = str(demos)
    result["n_transitions"] = len(arrays["actions"])
    if record is None:
        result["quit"] = True
        return result
    evaluation = out / "evaluation.json"
    write_json(evaluation, record)
    return {
        **result,
        **{k: record[k] for k in ("best_lap_time_s", "n_finished", "limit_lap_time_s", "best_lap")},
        "dnf_reason": timing.runs[0].dnf_reason,
        "evaluation_json": str(evaluation),
    }


#: The file of a human's runs of a setting, beside the time-trial row: RUNS/human/ALIAS-TRACK-CAR-setting-X/.
SETTING_ROW_NAME = "setting.json"


def play_setting(cfg: PlayConfig, events=None) -> dict[str, Any]:
    """The overtaking paper's human reference: ``cfg.setting_runs`` runs of setting A or B with a
    :class:`HumanDriver` (run k meets the opponents of every agent's run ``cfg.seed + k``), written as a row that
    ``evaluate-overtaking --human`` adds beside the agents. A run ended by the player ends the series; the runs
    before it are kept."""
    track = load_track(cfg.track)
    driver = HumanDriver(cfg.camera, cfg.window_hw_px, cfg.input, cfg.realtime, None, events)
    runs: list[dict[str, Any]] = []
    quit_run = False
    try:
        for k in range(cfg.setting_runs):
            try:
                rows, _ = run_setting(driver, track, cfg.car, cfg.setting, 1, cfg.seed + k, cfg.time_limit_s)
            except HumanQuit:
                quit_run = True
                break
            runs.append({**rows[0], "run": k})
    finally:
        driver.close()
    name = f"human ({cfg.name})"
    if not runs:
        return {"name": name, "setting": cfg.setting, "quit": True, "runs": []}
    row = {
        "name": name,
        "driver": {**driver.identity, "alias": cfg.name},
        "reference": True,
        "setting": cfg.setting,
        "track_name": track.name,
        "track_geometry_hash": track.geometry_hash,
        "car": cfg.car,
        "runs": runs,
        "summary": summarise_runs(runs),
    }
    out = Path(cfg.runs) / "human" / f"{cfg.name}-{track.name}-{cfg.car}-setting-{cfg.setting}" / SETTING_ROW_NAME
    out.parent.mkdir(parents=True, exist_ok=True)
    write_json(out, row)
    return {**row, "quit": quit_run, "setting_json": str(out)}
