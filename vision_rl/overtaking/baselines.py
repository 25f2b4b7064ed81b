"""`train-baseline`: each Table III algorithm sent to its learner (:mod:`.bc`, :mod:`.gail` beside
:mod:`.online`'s SAC, :mod:`.online` for TD3 and SAC, :mod:`.dreamer_train`), and a trained policy loaded back
whatever its algorithm. What the learners share lives below them, in :mod:`.baseline_run`."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vision_rl.files import run_folder_locked
from vision_rl.overtaking.baseline_run import (
    HIDDEN_UNITS,
    BaselineError,
    Progress,
    TrainBaselineConfig,
    baseline_algo,
    check_config,
    default_out,
)
from vision_rl.overtaking.bc import train_bc
from vision_rl.overtaking.config import OBSERVATION
from vision_rl.overtaking.demos import OBS_DIM
from vision_rl.overtaking.dreamer import LoadedDreamer
from vision_rl.overtaking.dreamer_train import load_dreamer, train_dreamer
from vision_rl.overtaking.gail import GAILCompanion
from vision_rl.overtaking.online import load_td3, train_online
from vision_rl.training.artifact import LoadedPolicy, PolicySpec, load_policy, resolve_policy_paths


@dataclass(frozen=True)
class Learner:
    """How one algorithm trains and loads."""

    train: Callable[..., dict[str, Any]]
    """``train(cfg, progress[, companion])``."""
    companion: Callable[[TrainBaselineConfig], Any] | None = None
    """What rides along the trainer (gail: a discriminator beside online SAC)."""
    load: Callable[[Path, PolicySpec, Path, str], Any] | None = None
    """``load(weights, spec, sidecar, device)``; None: an SB3 SAC policy, loaded like every SAC policy."""


#: Each algorithm and its learner.
ALGOS: dict[str, Learner] = {
    "bc": Learner(train_bc),
    "gail": Learner(train_online, companion=GAILCompanion),
    "td3": Learner(train_online, load=load_td3),
    "sac": Learner(train_online),
    "dreamer": Learner(train_dreamer, load=load_dreamer),
}


def train_baseline(cfg: TrainBaselineConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Train (or continue) one Table III baseline; returns its run record, the policy folder and the figures."""
    check_config(cfg)
    learner = ALGOS[cfg.algo]
    # Two runs in one folder (a --force of a running one) deleted each other's files: the second is refused.
    with run_folder_locked(Path(cfg.out) if cfg.out else default_out(cfg), "a running train-baseline"):
        if learner.companion is not None:
            return learner.train(cfg, progress, learner.companion(cfg))
        return learner.train(cfg, progress)


def load_baseline(
    path: str | os.PathLike[str], algo: str | None = None, device: str = "cpu"
) -> LoadedPolicy | LoadedDreamer:
    """A Table III policy (a train-baseline folder, or a train-overtaking stage-1 folder as SAC) ready to drive,
    refusing, in one line, a policy of another observation, network size or algorithm (``algo``), and every
    check of :func:`~vision_rl.training.artifact.load_policy` (checksum, fingerprint against the track)."""
    weights, sidecar = resolve_policy_paths(path)
    spec = PolicySpec.read(sidecar)
    if spec.observation != OBSERVATION:
        raise BaselineError(
            f"{sidecar}: the policy observes {spec.observation!r}, not the {OBS_DIM}-D {OBSERVATION!r} "
            "observation of the single-car race; give a train-baseline run"
        )
    recorded = baseline_algo(spec)
    if recorded not in ALGOS:
        raise BaselineError(f"{sidecar}: algorithm {recorded!r} is not one of {', '.join(ALGOS)}")
    if algo is not None and recorded != algo:
        raise BaselineError(f"{sidecar}: a {recorded} policy, not a {algo} one")
    units = spec.sac.get("hidden_units")
    if [int(u) for u in units or []] != list(HIDDEN_UNITS):
        raise BaselineError(f"{sidecar}: hidden units {units}, not the paper's {list(HIDDEN_UNITS)}")
    loader = ALGOS[recorded].load
    if loader is None:
        return load_policy(path, device=device)
    return loader(weights, spec, sidecar, device)
