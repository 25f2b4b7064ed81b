"""`train-repr`: learn phi_rep by regressing the 27 targets from frames (vision paper, section 3, equation 1).

The loss is the MSE on standardised targets; the weights with the lowest validation loss are kept and written as
``ckpt.pt``, and nothing here loads a file that can run code. ``lightning/last.ckpt`` is replaced atomically at every
epoch's end with the state of every random generator the run draws from, so that a run killed at any point resumes
from its last epoch's end to the weights it would have ended in (:class:`ResumableCheckpoint`). What is logged, what a
resume checks and how several devices train: docs/notes/phase1_repr.md.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import math
import os
import random
import shutil
import signal
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Checkpoint
from lightning.pytorch.plugins import TorchCheckpointIO

from vision_rl.datasets.augment import FrameAugmentation, target_mirror
from vision_rl.datasets.capture_dataset import TargetStandardiser
from vision_rl.files import atomic_write, write_json
from vision_rl.phase1_repr.checkpoint import save_checkpoint
from vision_rl.phase1_repr.config import TrainReprConfig, launch_rank
from vision_rl.phase1_repr.encoder import EncoderConfig, ReprNet
from vision_rl.signals import HeldSignal

#: Target groups reported with R^2, matched by name prefix; any other target lands in "other".
TARGET_GROUPS: dict[str, str] = {
    "edge_distances": "edge_distance_",
    "min_edge_distances": "min_distance_",
    "centre_offset": "centre_line_offset",
    "heading_angle": "heading_angle",
    "curvature_ahead": "curvature_",
}


def group_targets(target_names: Sequence[str]) -> dict[str, list[int]]:
    """Group name -> indices of its targets, in :data:`TARGET_GROUPS` order (empty groups left out)."""
    groups: dict[str, list[int]] = {}
    for i, name in enumerate(target_names):
        group = next((g for g, prefix in TARGET_GROUPS.items() if name.startswith(prefix)), "other")
        groups.setdefault(group, []).append(i)
    order = [*TARGET_GROUPS, "other"]
    return {g: groups[g] for g in order if g in groups}


def regression_metrics(pred: np.ndarray, true: np.ndarray, target_names: Sequence[str]) -> dict[str, Any]:
    """RMSE per target (physical units) and R^2 per group: 1 - sum of squared errors / sum of squares about each
    target's own mean, pooled over the group's targets (NaN for a group whose targets do not vary)."""
    pred = np.asarray(pred, dtype=np.float64)
    true = np.asarray(true, dtype=np.float64)
    err2 = (pred - true) ** 2
    rmse = np.sqrt(err2.mean(axis=0))
    dev2 = (true - true.mean(axis=0)) ** 2
    r2 = {}
    for group, idx in group_targets(target_names).items():
        ss_tot = dev2[:, idx].sum()
        r2[group] = float(1.0 - err2[:, idx].sum() / ss_tot) if ss_tot > 0 else float("nan")
    return {"rmse": {n: float(v) for n, v in zip(target_names, rmse, strict=True)}, "r2": r2}


class ReprModule(L.LightningModule):
    """The representation network with its training loop (AdamW, cosine schedule, MSE on standardised targets)."""

    def __init__(
        self,
        encoder_config: dict[str, Any],
        target_names: list[str],
        target_units: list[str],
        target_mean: list[float],
        target_std: list[float],
        lr: float = 2e-3,
        weight_decay: float = 1e-4,
        augmentation: dict[str, Any] | None = None,
        mirror: bool = False,
        balance_groups: bool = False,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.net = ReprNet(EncoderConfig.from_dict(encoder_config))
        self.augment = FrameAugmentation(**augmentation) if augmentation else None
        self.register_buffer("target_mean", torch.tensor(target_mean, dtype=torch.float32))
        self.register_buffer("target_std", torch.tensor(target_std, dtype=torch.float32))
        weights = np.ones(len(target_names))
        if balance_groups:
            groups = group_targets(target_names).values()
            for idx in groups:
                weights[idx] = len(target_names) / (len(groups) * len(idx))
        self.register_buffer("loss_weights", torch.as_tensor(weights, dtype=torch.float32), persistent=False)
        if mirror:
            perm, sign = target_mirror(target_names)
            self.register_buffer("mirror_perm", torch.as_tensor(perm), persistent=False)
            self.register_buffer("mirror_sign", torch.as_tensor(sign, dtype=torch.float32), persistent=False)
        self._val_pred: list[torch.Tensor] = []
        self._val_true: list[torch.Tensor] = []
        self.last_val_metrics: dict[str, Any] | None = None
        # Reset at every epoch's start; a resume from inside an epoch starts none (its mean is the resumed part's).
        self._train_loss_sum, self._train_loss_count = 0.0, 0
        # Augmentation and mirroring draw from a generator of their own (on the CPU), seeded by train_repr and kept in
        # last.ckpt: a resume draws what the uninterrupted run would have drawn, whatever the loaders drew meanwhile.
        self.draws = torch.Generator()

    def predict_standardised(self, images: torch.Tensor, augment: bool = False) -> torch.Tensor:
        x = self.net.frames_to_unit(images)
        if augment and self.augment is not None and self.augment.enabled:
            x = self.augment(x, self.draws)
        return self.net.phi_reg(self.net.embed_unit(x))

    def on_train_epoch_start(self) -> None:
        self._train_loss_sum, self._train_loss_count = 0.0, 0

    def train_loss_mean(self) -> float | None:
        """Mean training loss of the current epoch so far (validation runs before Lightning's epoch aggregate)."""
        count = self._train_loss_count
        return self._train_loss_sum / count if count else None

    def loss(self, pred: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """MSE on standardised targets, each weighted by ``loss_weights`` (mean 1)."""
        return ((pred - targets) ** 2 * self.loss_weights).mean()

    def mirror_half(self, images: torch.Tensor, targets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Mirror a random half of uint8 frames (N, H, W, 3) left-right, with their standardised targets."""
        flip = (torch.rand(len(images), generator=self.draws) < 0.5).to(images.device)
        physical = targets * self.target_std + self.target_mean
        mirrored = (physical[:, self.mirror_perm] * self.mirror_sign - self.target_mean) / self.target_std
        return (
            torch.where(flip.view(-1, 1, 1, 1), images.flip(2), images),
            torch.where(flip.view(-1, 1), mirrored, targets),
        )

    def training_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int) -> torch.Tensor:
        images, targets = batch
        if self.hparams.mirror:
            images, targets = self.mirror_half(images, targets)
        loss = self.loss(self.predict_standardised(images, augment=True), targets)
        self.log(
            "train_loss",
            loss,
            on_step=True,
            on_epoch=True,
            prog_bar=True,
            batch_size=len(images),
            sync_dist=self.trainer.world_size > 1,
        )
        self._train_loss_sum += float(loss.detach()) * len(images)
        self._train_loss_count += len(images)
        return loss

    def validation_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int) -> None:
        images, targets = batch
        pred = self.predict_standardised(images)
        # sync_dist: every process keeps the same best epoch (the mean over all of them; a no-op on one device).
        self.log(
            "val_loss", self.loss(pred, targets), on_epoch=True, prog_bar=True, batch_size=len(images), sync_dist=True
        )
        self._val_pred.append((pred * self.target_std + self.target_mean).detach().cpu())
        self._val_true.append((targets * self.target_std + self.target_mean).detach().cpu())

    def on_validation_epoch_end(self) -> None:
        if not self._val_pred:
            return
        pred, true = torch.cat(self._val_pred), torch.cat(self._val_true)
        self._val_pred.clear()
        self._val_true.clear()
        if self.trainer.world_size > 1:  # every process's share of the validation frames
            pred, true = (self.all_gather(x).reshape(-1, x.shape[-1]).cpu() for x in (pred, true))
        pred, true = pred.numpy(), true.numpy()
        metrics = regression_metrics(pred, true, self.hparams.target_names)
        self.last_val_metrics = metrics
        if self.trainer.sanity_checking:
            return
        # The same values in every process (gathered above): sync_dist only tells Lightning they are whole.
        for name, value in metrics["rmse"].items():
            self.log(f"val_rmse/{name}", value, sync_dist=True)
        for group, value in metrics["r2"].items():
            if np.isfinite(value):
                self.log(f"val_r2/{group}", value, sync_dist=True)

    def configure_optimizers(self) -> dict[str, Any]:
        decay = [p for n, p in self.named_parameters() if p.ndim > 1]
        no_decay = [p for n, p in self.named_parameters() if p.ndim <= 1]  # biases and norms: no weight decay
        optimiser = torch.optim.AdamW(
            [{"params": decay, "weight_decay": self.hparams.weight_decay}, {"params": no_decay, "weight_decay": 0.0}],
            lr=self.hparams.lr,
        )
        total = max(1, int(self.trainer.estimated_stepping_batches))
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=total)
        return {"optimizer": optimiser, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}


class MetricsHistory(L.Callback):
    """Writes ``metrics.json`` after every validation epoch; its history survives a resume (callback state)."""

    def __init__(self, path: Path, target_units: Sequence[str], target_names: Sequence[str]) -> None:
        self.path = Path(path)
        self.units = dict(zip(target_names, target_units, strict=True))
        self.epochs: list[dict[str, Any]] = []

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # on_validation_end, not on_validation_epoch_end: Lightning calls callbacks' epoch-end hooks before the
        # module's, which computes the metrics. Checkpoint callbacks run after this one, so they save this record.
        if trainer.sanity_checking or not isinstance(pl_module, ReprModule) or pl_module.last_val_metrics is None:
            return
        logged = trainer.callback_metrics
        record = {
            "epoch": int(trainer.current_epoch),
            "step": int(trainer.global_step),
            "val_loss": float(logged["val_loss"]) if "val_loss" in logged else None,
            "train_loss": pl_module.train_loss_mean(),
            "val_rmse": pl_module.last_val_metrics["rmse"],
            "val_r2": pl_module.last_val_metrics["r2"],
        }
        self.epochs = [e for e in self.epochs if e["epoch"] != record["epoch"]] + [record]
        if trainer.is_global_zero:
            self.write()

    def best(self) -> dict[str, Any] | None:
        scored = [e for e in self.epochs if e["val_loss"] is not None]
        return min(scored, key=lambda e: e["val_loss"]) if scored else None

    def write(self, extra: dict[str, Any] | None = None) -> None:
        payload = {"units": self.units, "epochs": self.epochs, "best": self.best(), **(extra or {})}
        write_json(self.path, payload)

    def state_dict(self) -> dict[str, Any]:
        return {"epochs": self.epochs}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.epochs = list(state_dict.get("epochs", []))


class BestWeights(L.Callback):
    """Keeps a CPU copy of the network's weights at the epoch with the lowest validation loss.

    The copy is a state dict (tensors only), in memory and in the callback state that Lightning's ``last.ckpt``
    carries, so a resumed run keeps the best weights of its earlier epochs; ``ckpt.pt`` is written from it without
    loading any Lightning checkpoint."""

    def __init__(self) -> None:
        self.epoch: int | None = None
        self.val_loss: float | None = None
        self.weights: dict[str, torch.Tensor] = {}

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or "val_loss" not in trainer.callback_metrics:
            return
        loss = float(trainer.callback_metrics["val_loss"])
        if math.isfinite(loss) and (self.val_loss is None or loss < self.val_loss):
            assert isinstance(pl_module, ReprModule)
            self.epoch, self.val_loss = int(trainer.current_epoch), loss
            self.weights = {k: v.detach().cpu().clone() for k, v in pl_module.net.state_dict().items()}

    def state_dict(self) -> dict[str, Any]:
        return {"epoch": self.epoch, "val_loss": self.val_loss, "weights": self.weights}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.epoch, self.val_loss = state_dict.get("epoch"), state_dict.get("val_loss")
        self.weights = dict(state_dict.get("weights", {}))


#: ``progress(steps_done, steps_total, figures)``: called by :func:`train_repr` after every optimiser step and every
#: validation; ``figures`` holds the epoch and the latest ``train_loss`` / ``val_loss``.
TrainProgress = Callable[[int, int, dict[str, float]], None]


class _ReportProgress(L.Callback):
    """Hands the step count and the latest losses to a :data:`TrainProgress` callback."""

    def __init__(self, report: TrainProgress) -> None:
        self.report = report
        self.figures: dict[str, float] = {}

    def _send(self, trainer: L.Trainer) -> None:
        total = trainer.estimated_stepping_batches
        self.figures["epoch"] = int(trainer.current_epoch)
        self.report(int(trainer.global_step), int(total) if math.isfinite(total) else 0, dict(self.figures))

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs, batch, batch_idx) -> None:
        metrics = trainer.callback_metrics
        loss = metrics.get("train_loss_step", metrics.get("train_loss"))
        if loss is not None:
            self.figures["train_loss"] = float(loss)
        self._send(trainer)

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.sanity_checking and "val_loss" in trainer.callback_metrics:
            self.figures["val_loss"] = float(trainer.callback_metrics["val_loss"])
            self._send(trainer)


class _Throughput(L.Callback):
    """Training frames per second over all processes: the time from each training epoch's start to its last batch
    (data loading included, validation excluded), the frames of this process times the number of processes (the
    distributed sampler gives each as many)."""

    def __init__(self) -> None:
        self.frames = 0
        self.seconds = 0.0
        self._last_batch_end = 0.0

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._last_batch_end = time.perf_counter()

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs, batch, batch_idx) -> None:
        now = time.perf_counter()
        self.seconds += now - self._last_batch_end
        self._last_batch_end = now
        self.frames += len(batch[0]) * trainer.world_size

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0


class _AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning's checkpoint writer, through the package's one atomic write: staged beside the file and renamed.

    Lightning's own stages the file in the system's temporary folder and moves it across filesystems, which a full
    disk cuts short; here a failed write raises :class:`~vision_rl.files.ArtifactWriteError` naming the file, and
    the previous checkpoint stays whole."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None) -> None:
        buffer = io.BytesIO()
        torch.save(checkpoint, buffer)  # serialised first: a full disk then fails a plain write, with ENOSPC
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, lambda tmp: tmp.write_bytes(buffer.getbuffer()))


def random_states() -> dict[str, Any]:
    """This process's random generators: torch's (the CPU's, and each CUDA device's once CUDA is in use), NumPy's
    and Python's, as tensors and plain values (a checkpoint of them loads with ``weights_only=True``)."""
    _, keys, pos, has_gauss, cached_gaussian = np.random.get_state()  # noqa: NPY002 (the one seed_everything seeds)
    version, internal, gauss_next = random.getstate()
    cuda = torch.cuda.get_rng_state_all() if torch.cuda.is_available() and torch.cuda.is_initialized() else []
    return {
        "torch": torch.get_rng_state(),
        "cuda": cuda,
        "numpy": {
            "keys": torch.from_numpy(keys.astype(np.int64)),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "cached_gaussian": float(cached_gaussian),
        },
        "python": {"version": int(version), "internal": list(internal), "gauss_next": gauss_next},
    }


def set_random_states(states: dict[str, Any]) -> None:
    """Restore what :func:`random_states` returned (CUDA's only on as many devices as it was taken on)."""
    torch.set_rng_state(states["torch"])
    cuda = states.get("cuda") or []
    if cuda and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(cuda)
    numpy = states["numpy"]
    keys = numpy["keys"].numpy().astype(np.uint32)
    np.random.set_state(("MT19937", keys, numpy["pos"], numpy["has_gauss"], numpy["cached_gaussian"]))  # noqa: NPY002
    python = states["python"]
    random.setstate((python["version"], tuple(python["internal"]), python["gauss_next"]))


class TrainingOrder:
    """The order of the training frames, drawn apart from torch's global generator, which the loaders also draw their
    workers' seeds from (a loader that keeps its workers from epoch to epoch draws once, when it starts, and a resumed
    run starts its loaders again): on one device a RandomSampler drawing from ``generator``; on several, the
    distributed sampler of Lightning's (from the seed and the epoch), made here so that a resume sets its ``epoch``
    before the loader's workers take the resumed epoch's order."""

    def __init__(self, seed: int) -> None:
        self.seed = seed
        self.generator = torch.Generator().manual_seed(seed)
        self.epoch = 0  # the epoch a distributed sampler starts at: a resume's first

    def install(self, dm) -> None:
        """Make ``dm``'s training loader draw its order here."""
        make_train = dm.train_dataloader
        dm.train_dataloader = lambda: self._loader(make_train())

    def _loader(self, loader: torch.utils.data.DataLoader) -> torch.utils.data.DataLoader:
        if not (torch.distributed.is_available() and torch.distributed.is_initialized()):
            if isinstance(loader.sampler, torch.utils.data.RandomSampler):
                loader.sampler.generator = self.generator
            return loader
        sampler = torch.utils.data.DistributedSampler(loader.dataset, shuffle=True, seed=self.seed)
        sampler.set_epoch(self.epoch)
        return torch.utils.data.DataLoader(
            loader.dataset,
            batch_size=loader.batch_size,
            sampler=sampler,
            drop_last=loader.drop_last,
            num_workers=loader.num_workers,
            collate_fn=loader.collate_fn,
            persistent_workers=loader.persistent_workers,
            pin_memory=loader.pin_memory,
        )


class ResumableCheckpoint(Checkpoint):
    """Saves ``last.ckpt``, what ``--resume`` reads, at every epoch's end and every ``every_min`` minutes inside
    epochs (0: never inside), through :class:`_AtomicCheckpointIO`.

    Its state in the file is every random generator the run draws from (the frames' order, :class:`TrainingOrder`,
    the augmentation's, ``ReprModule.draws``, and :func:`random_states`), restored on a resume, so that a run
    resumed from an epoch's end draws what the uninterrupted run would have drawn and ends in the same weights, bit
    for bit. Every process of a DDP run calls the save (Lightning's rank 0 writes); rank 0's clock decides when a
    timed save is due."""

    def __init__(self, path: Path, every_min: float, order: TrainingOrder, draws: torch.Generator) -> None:
        self.path = Path(path)
        self.every_s = 60.0 * every_min
        self.order = order
        self.generators = {"order": order.generator, "augmentation": draws}
        self.finished_epochs = 0  # epochs the file on disk holds
        self.saved_step = 0  # and its optimiser steps
        self._finished_in_save = self._step_in_save = 0
        self._last_save_s = time.monotonic()

    def _save(self, trainer: L.Trainer, finished_epochs: int) -> None:
        self._finished_in_save, self._step_in_save = finished_epochs, int(trainer.global_step)
        trainer.save_checkpoint(self.path)
        self.finished_epochs, self.saved_step = finished_epochs, int(trainer.global_step)
        self._last_save_s = time.monotonic()

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._last_save_s = time.monotonic()

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs, batch, batch_idx) -> None:
        if self.every_s > 0 and trainer.strategy.broadcast(time.monotonic() - self._last_save_s >= self.every_s):
            self._save(trainer, self.finished_epochs)

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # After validation (Lightning validates before this hook): the file holds the epoch's metrics and best weights.
        self._save(trainer, int(trainer.current_epoch) + 1)

    def state_dict(self) -> dict[str, Any]:
        return {
            "random": random_states(),
            "generators": {name: g.get_state() for name, g in self.generators.items()},
            "finished_epochs": self._finished_in_save,
            "step": self._step_in_save,
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.finished_epochs = self._finished_in_save = int(state_dict.get("finished_epochs", 0))
        self.saved_step = self._step_in_save = int(state_dict.get("step", 0))
        self.order.epoch = self.finished_epochs  # the epoch the file ends in, or the one it was saved inside
        if "random" in state_dict:  # a last.ckpt of an older version has none: it resumes, drawing otherwise
            set_random_states(state_dict["random"])
            for name, g in self.generators.items():
                g.set_state(state_dict["generators"][name])


class TrainingInterrupted(KeyboardInterrupt):
    """SIGTERM or Ctrl-C stopped :func:`train_repr`: ``last_ckpt`` (None when no epoch had ended) holds
    ``finished_epochs`` epochs and ``optimiser_steps`` steps; ``resume`` goes on from there. A KeyboardInterrupt, so
    that a caller that does not look for it stops as on Ctrl-C."""

    def __init__(self, last_ckpt: Path | None, finished_epochs: int, optimiser_steps: int) -> None:
        super().__init__(f"interrupted; {last_ckpt or 'no last.ckpt'}")
        self.last_ckpt = last_ckpt
        self.finished_epochs = finished_epochs if last_ckpt else 0
        self.optimiser_steps = optimiser_steps if last_ckpt else 0


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


class _HoldToBatchEdge(L.Callback):
    """Once training starts, puts ``handler`` back as SIGTERM's over Lightning's and holds the first SIGINT or SIGTERM
    (:class:`~vision_rl.signals.HeldSignal`) to the next edge of a batch (a training or validation batch's start or
    end, or the training's end), where ``handler`` (or Python's, for Ctrl-C) raises KeyboardInterrupt: Lightning then
    stops, and on several devices rank 0 kills the others. A second signal acts at once.

    Lightning's own SIGTERM handler notes the signal too, but on several devices broadcasts from inside the handler,
    which deadlocks a process caught in another collective."""

    def __init__(self, handler: Callable[[int, Any], Any]) -> None:
        self.handler = handler
        self.held = HeldSignal()
        self._holding = contextlib.ExitStack()

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, self.handler)
        self._holding.enter_context(self.held.installed())

    def _release(self, *hook_args: Any, **hook_kwargs: Any) -> None:
        self.held.release()

    def _stop_holding(self, *hook_args: Any, **hook_kwargs: Any) -> None:
        self._holding.close()  # the handlers of before, and a signal still held acted on

    on_train_batch_start = on_train_batch_end = on_validation_batch_start = on_validation_batch_end = _release
    on_train_end = on_exception = _stop_holding


def _lightning_dir(out: Path) -> Path:
    return out / "lightning"


@contextlib.contextmanager
def _quiet_lightning() -> Iterator[None]:
    """Lightning logs hardware summaries and tips at INFO on every fit, and Lightning 2.6 warns about its own use of
    torch's pytree API; the command's own output is what matters."""
    logger = logging.getLogger("lightning.pytorch")
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)")
            # DDP: the depthwise convolutions' gradients are laid out otherwise than DDP's buckets (DDP copies them),
            # and Lightning's all_gather goes through a torch function torch deprecates.
            warnings.filterwarnings("ignore", message=r"Grad strides do not match bucket view strides")
            warnings.filterwarnings("ignore", message=r".*all_gather is deprecated")
            # A resume from a timed save inside an epoch (--checkpoint-every-min says what it costs), and one from a
            # last.ckpt of an older version, whose checkpoint callback this one replaces.
            warnings.filterwarnings("ignore", message=r"You're resuming from a checkpoint that ended before")
            warnings.filterwarnings("ignore", message=r"Be aware that when using `ckpt_path`")
            yield
    finally:
        logger.setLevel(level)


def _check_run_folder(cfg: TrainReprConfig, out: Path, last_ckpt: Path, rank: int) -> None:
    """Refuse a resume without a last checkpoint or from one that could run code, and a folder holding a run unless
    ``force`` (then it is emptied, by rank 0)."""
    if cfg.resume and not last_ckpt.is_file():
        raise FileNotFoundError(f"{out}: nothing to resume (no {last_ckpt.name})")
    if cfg.resume:
        _check_plain_checkpoint(last_ckpt)
    if rank == 0 and not cfg.resume and (last_ckpt.exists() or (out / "ckpt.pt").exists()):
        if not cfg.force:
            raise FileExistsError(f"{out} holds a run: resume it (--resume) or start over (--force)")
        shutil.rmtree(out)


def _data(cfg: TrainReprConfig, out: Path, rank: int):
    """The data module, set up, and the record of its capture files (``data.json``, checked against the run's on a
    resume, written by rank 0)."""
    from vision_rl.datasets.datamodule import CaptureDataModule

    dm = CaptureDataModule(
        cfg.data,
        cfg.val or None,
        val_fraction=cfg.val_fraction,
        split_seed=cfg.seed,
        batch_size=cfg.batch_size,
        num_workers=cfg.num_workers,
    )
    dm.prepare_data()
    dm.setup("fit")  # reads the targets and refuses non-finite or absurd ones, before anything is trained
    assert dm.standardiser is not None and dm.val_set is not None
    dataset = {
        "train": [dict(s) for s in dm.catalogue.sources],
        "val": [dict(s) for s in dm.val_set.catalogue.sources] if cfg.val else "laps held out of train",
    }
    data_json = out / "data.json"
    if cfg.resume:
        _check_same_data(data_json, dataset)
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        write_json(data_json, dataset)
    return dm, dataset


def _repr_module(cfg: TrainReprConfig, dm) -> tuple[EncoderConfig, ReprModule]:
    """The encoder's configuration for the data's frame size and the Lightning module that trains it."""
    catalogue = dm.catalogue
    h, w = catalogue.image_hw_px
    enc_cfg = EncoderConfig(
        backbone=cfg.backbone,
        input_height_px=h,
        input_width_px=w,
        space2depth_block=cfg.space2depth_block_px,
        n_targets=len(catalogue.target_names),
    ).scaled(cfg.width_mult)
    photometric = {} if cfg.augment else {"brightness": 0.0, "contrast": 0.0, "saturation": 0.0}
    augment = FrameAugmentation(shift_px=cfg.shift_px, **photometric)
    augmentation = dataclasses.asdict(augment) if augment.enabled else None
    module = ReprModule(
        encoder_config=enc_cfg.to_dict(),
        target_names=list(catalogue.target_names),
        target_units=list(catalogue.target_units),
        target_mean=dm.standardiser.mean.tolist(),
        target_std=dm.standardiser.std.tolist(),
        lr=cfg.lr,
        weight_decay=cfg.weight_decay,
        augmentation=augmentation,
        mirror=cfg.mirror,
        balance_groups=cfg.balance_groups,
    )
    return enc_cfg, module


def _fit(cfg: TrainReprConfig, out: Path, module: ReprModule, dm, callbacks: list[L.Callback]) -> L.Trainer:
    """Lightning's fit of ``module`` on ``dm`` (from ``last.ckpt`` on a resume); returns the trainer, whose
    ``interrupted`` says that a signal stopped the fit."""
    from lightning.pytorch.loggers import TensorBoardLogger

    # Lightning ignores Ctrl-C from the first one on: the caller's handler comes back when the fit ends.
    main_thread = threading.current_thread() is threading.main_thread()
    sigint, sigterm = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    callbacks = [*callbacks, _HoldToBatchEdge(sigterm if callable(sigterm) else _raise_interrupt)]
    with _quiet_lightning():
        trainer = L.Trainer(
            accelerator=cfg.device if cfg.device != "auto" else "auto",
            devices=cfg.devices,
            strategy=cfg.strategy,
            precision=cfg.precision,
            max_epochs=cfg.epochs,
            max_steps=cfg.max_steps,
            logger=TensorBoardLogger(save_dir=str(out), name="tensorboard", version=""),
            callbacks=callbacks,
            plugins=[_AtomicCheckpointIO()],
            enable_progress_bar=False,
            enable_model_summary=False,
            num_sanity_val_steps=0,
            log_every_n_steps=max(1, min(50, len(dm.train_set) // max(1, cfg.batch_size))),
            deterministic=False,
        )
        last_ckpt = _lightning_dir(out) / "last.ckpt"
        try:
            trainer.fit(module, datamodule=dm, ckpt_path=str(last_ckpt) if cfg.resume else None, weights_only=True)
        except (KeyboardInterrupt, SystemExit):
            # Lightning ends a fit that Ctrl-C (or a handler's KeyboardInterrupt) stopped with sys.exit(1), and one
            # that its own SIGTERM handler stopped with SystemExit; either way it marks the trainer interrupted.
            if not trainer.interrupted:
                raise
        finally:
            if main_thread and signal.getsignal(signal.SIGINT) is not sigint and sigint is not None:
                signal.signal(signal.SIGINT, sigint)
    return trainer


def _write_kept(
    out: Path,
    enc_cfg: EncoderConfig,
    module: ReprModule,
    best_weights: BestWeights,
    history: MetricsHistory,
    dm,
    dataset: dict[str, Any],
    device: torch.device,
) -> tuple[Path, Path, dict[str, Any]]:
    """Write ``ckpt.pt``, the predicted-vs-true figure and the final ``metrics.json``; returns their paths and the
    kept epoch's figures.

    The kept weights: the best validation epoch's, or the last ones when no validation finished (max_steps stopped
    the run inside its first epoch)."""
    net = ReprNet(EncoderConfig.from_dict(enc_cfg.to_dict()))
    net.load_state_dict(best_weights.weights or {k: v.detach().cpu() for k, v in module.net.state_dict().items()})
    net.eval()
    best = next((e for e in history.epochs if e["epoch"] == best_weights.epoch), None) or {}
    catalogue = dm.catalogue
    ckpt_path = save_checkpoint(
        out / "ckpt.pt",
        net,
        target_names=catalogue.target_names,
        target_units=catalogue.target_units,
        target_mean=dm.standardiser.mean,
        target_std=dm.standardiser.std,
        metrics={k: best[k] for k in ("epoch", "val_loss", "val_r2", "val_rmse") if k in best},
        dataset=dataset,
    )
    pred, true = predict_dataset(net, dm.val_dataloader(), dm.standardiser, device)
    figure = plot_predictions(pred, true, catalogue.target_names, catalogue.target_units, out / "pred_vs_true.png")
    history.write({"ckpt": str(ckpt_path), "figure": str(figure)})
    return ckpt_path, figure, best


def train_repr(cfg: TrainReprConfig, progress: TrainProgress | None = None) -> dict[str, Any]:
    """Run training as configured; returns the paths written and the kept epoch's figures. Prints nothing;
    ``progress`` (see :data:`TrainProgress`) hears of every step.

    ``lightning/last.ckpt`` is saved at every epoch's end (see :class:`ResumableCheckpoint`). A run stopped by
    SIGTERM or Ctrl-C writes no ``ckpt.pt`` (the weights of a cut-short run are not a result): it raises
    :class:`TrainingInterrupted`, which says what ``last.ckpt`` holds, and ``resume`` goes on from there."""
    if not cfg.data:
        raise ValueError("training needs data: one or more capture files (--data)")
    out = Path(cfg.out)
    # A process the DDP launcher started: rank 0 has checked and prepared the run folder; this one only trains.
    rank = launch_rank()
    _check_run_folder(cfg, out, _lightning_dir(out) / "last.ckpt", rank)
    L.seed_everything(cfg.seed, workers=True, verbose=False)
    dm, dataset = _data(cfg, out, rank)
    order = TrainingOrder(cfg.seed)
    order.install(dm)
    on_cpu = cfg.device == "cpu" or (cfg.device == "auto" and not torch.cuda.is_available())
    if on_cpu and cfg.devices > 1:
        # Processes share the machine's cores: torch's threads per process are the cores' share, not all of them.
        torch.set_num_threads(max(1, len(os.sched_getaffinity(0)) // cfg.devices))
    enc_cfg, module = _repr_module(cfg, dm)
    module.draws.manual_seed(cfg.seed)
    history = MetricsHistory(out / "metrics.json", dm.catalogue.target_units, dm.catalogue.target_names)
    best_weights = BestWeights()
    throughput = _Throughput()
    # Only last.ckpt, for --resume: the best weights travel in BestWeights' state inside it.
    keeper = ResumableCheckpoint(_lightning_dir(out) / "last.ckpt", cfg.checkpoint_every_min, order, module.draws)
    callbacks = [best_weights, history, keeper, throughput, *([_ReportProgress(progress)] if progress else [])]
    trainer = _fit(cfg, out, module, dm, callbacks)
    if trainer.interrupted or not trainer.is_global_zero:  # rank 0 writes ckpt.pt, the figure and metrics.json
        dm.train_set.close()
        dm.val_set.close()
        if trainer.interrupted:
            saved = keeper.path.is_file()
            raise TrainingInterrupted(keeper.path if saved else None, keeper.finished_epochs, keeper.saved_step)
        return {"rank": int(trainer.global_rank)}
    device = trainer.strategy.root_device
    ckpt_path, figure, best = _write_kept(out, enc_cfg, module, best_weights, history, dm, dataset, device)
    dm.train_set.close()
    dm.val_set.close()
    tensorboard = out / "tensorboard"
    return {
        "ckpt": str(ckpt_path),
        "metrics_json": str(out / "metrics.json"),
        "figure": str(figure),
        "tensorboard": str(tensorboard) if tensorboard.is_dir() else None,
        "best_epoch": best.get("epoch"),
        "val_loss": best.get("val_loss"),
        "val_r2": best.get("val_r2"),
        "val_rmse": best.get("val_rmse"),
        "n_train_frames": len(dm.train_set),
        "n_val_frames": len(dm.val_set),
        "devices": int(trainer.world_size),
        "optimiser_steps": int(trainer.global_step),
        "train_frames_per_s": throughput.frames_per_s,
        "train_time_s": throughput.seconds,
    }


def _check_plain_checkpoint(path: Path) -> None:
    """Refuse a Lightning checkpoint that holds anything but tensors and plain values: loading it would run code."""
    try:
        torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises UnpicklingError, RuntimeError, EOFError... for a bad or unsafe file
        # torch's own message suggests loading the file unrestricted: not advice to pass on for an untrusted file.
        reason = type(exc).__name__
        raise ValueError(
            f"{path}: not a checkpoint of plain tensors and values ({reason}: damaged, or it holds objects whose "
            "loading could run code); refusing to load it: start the run over with --force"
        ) from None


def _check_same_data(data_json: Path, dataset: dict[str, Any]) -> None:
    """A resumed run must train on the data it started with: refuse the first differing field."""
    from vision_rl.capture.h5format import first_difference

    try:
        before = json.loads(data_json.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(
            f"{data_json}: cannot read the data the run started with ({exc}): start over with --force"
        ) from exc
    diff = first_difference(before, dataset, "data")
    if diff is not None:
        field, was, now = diff
        raise ValueError(
            f"{data_json.parent}: cannot resume on other data: {field} was {was!r}, now {now!r}; resume with the "
            "run's data or start over with --force"
        )


@torch.no_grad()
def predict_dataset(
    net: ReprNet, loader: torch.utils.data.DataLoader, standardiser: TargetStandardiser, device: torch.device
) -> tuple[np.ndarray, np.ndarray]:
    """Predictions and truths in physical units over a loader of (uint8 frames, standardised targets)."""
    net = net.to(device).eval()
    preds, trues = [], []
    for images, targets in loader:
        _, standardised = net(images.to(device))
        preds.append(standardised.float().cpu().numpy())
        trues.append(targets.numpy())
    return standardiser.inverse(np.concatenate(preds)), standardiser.inverse(np.concatenate(trues))


def plot_predictions(
    pred: np.ndarray, true: np.ndarray, target_names: Sequence[str], target_units: Sequence[str], path: Path
) -> Path:
    """One scatter of predicted against true values per target group, with the identity line and R^2."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = group_targets(target_names)
    r2 = regression_metrics(pred, true, target_names)["r2"]
    fig, axes = plt.subplots(1, len(groups), figsize=(4 * len(groups), 4), squeeze=False)
    rng = np.random.default_rng(0)
    for ax, (group, idx) in zip(axes[0], groups.items(), strict=True):
        t, p = true[:, idx].ravel(), pred[:, idx].ravel()
        if len(t) > 20_000:  # keep the figure light: a random subset shows the same spread
            keep = rng.choice(len(t), 20_000, replace=False)
            t, p = t[keep], p[keep]
        ax.scatter(t, p, s=2, alpha=0.3)
        lo, hi = float(min(t.min(), p.min())), float(max(t.max(), p.max()))
        ax.plot([lo, hi], [lo, hi], "k--", lw=1)
        ax.set_title(f"{group}  R²={r2[group]:.3f}")
        unit = target_units[idx[0]]
        ax.set_xlabel(f"true ({unit})")
        ax.set_ylabel(f"predicted ({unit})")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
