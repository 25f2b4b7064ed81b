"""The DDPG paper's options: the agent's hyper-parameters (:class:`DDPGHyper`, the paper's Table 2), what
`train-ddpg` trains (:class:`TrainDDPGConfig`) and their checks, and the reference check's shared recipe. Light (no
torch), so that `train-ddpg --help` and `ddpg-reference --help` answer without loading the agent (issue 62)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from vision_rl.budget import array_bytes, require_memory
from vision_rl.config import Bounds, at_least, check_option_bounds, nested
from vision_rl.envs.pixel_racing import PixelRacingConfig
from vision_rl.training.schedules import CheckpointSchedule, EvaluationSchedule, SamplerOptions

VARIANTS = ("asymmetric", "symmetric", "state-actor")
PEDAL_ACTIVATIONS = ("relu", "sigmoid")
#: The conv trunk's presets (:data:`vision_rl.ddpg.agent.TRUNK_LAYERS`).
TRUNK_PRESETS = ("paper", "cpu")
#: Memory layouts and compilation of the convolutions that :func:`vision_rl.ddpg.bench.bench_updates` times.
BENCH_LAYOUTS = ("eager", "channels_last", "compiled")


class DDPGError(ValueError):
    """An agent, checkpoint or input that does not fit (another variant, frame size, track); the message says why."""


class FrameSizeError(DDPGError):
    """Frames of a size the network was not built for."""


@dataclass(frozen=True)
class DDPGHyper:
    """DDPG hyper-parameters (the paper's Table 2 by default)."""

    variant: str = "asymmetric"
    """asymmetric (pixel actor, motion + goal critic), symmetric (the critic on pixels too), state-actor."""
    actor_lr: float = 1e-3
    """Adam step size of the actor."""
    critic_lr: float = 1e-4
    """Adam step size of the critic."""
    tau: float = 0.01
    """Soft update of the target networks."""
    gamma: float = 0.98
    """Discount per control step."""
    batch_size: int = 32
    """Transitions per update."""
    buffer_size: int = 100_000
    """Replay capacity, rows (frames) over all cars: 100,000 89x120 frames take 3.2 GB."""
    ou_theta: float = 0.8
    """Ornstein-Uhlenbeck mean reversion per unit time."""
    ou_sigma: float = 0.3
    """Ornstein-Uhlenbeck noise scale."""
    ou_mu: float = 0.0
    """Ornstein-Uhlenbeck mean."""
    ou_dt: float = 1.0
    """Ornstein-Uhlenbeck time step per control step (1: x <- x + theta (mu - x) + sigma N, the Keras DDPG code's)."""
    output_init_scale: float = 1e-2
    """Variance-scaling scale of the actor's output layer."""
    pedal_activation: str = "relu"
    """Output activation of the accelerate and brake keys: relu (the paper's; a pedal whose pre-activation turns
    negative passes no gradient, so the actor can never press it again) or sigmoid (never without a gradient; a fresh
    actor holds both pedals half the step, as it holds both steering keys)."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this in the critic's targets (1: the paper's)."""
    channels_last: bool = True
    """Run the convolutions in channels-last memory format (faster on CPUs; the frames already are)."""
    batch_norm: bool = True
    """Batch-norm after every hidden layer's ReLU (the paper's); False: plain ReLU layers, as Stable-Baselines3's."""
    trunk: str = "paper"
    """The pixel networks' conv trunk: paper (four 2x2 stride-1 convolutions, each max-pooled) or cpu (the first two
    strided 2, the last two unpooled: about a tenth of the multiply-adds; not in the paper)."""

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise DDPGError(f"variant must be one of {VARIANTS}, got {self.variant!r}")
        if self.trunk not in TRUNK_PRESETS:
            raise DDPGError(f"trunk must be one of {TRUNK_PRESETS}, got {self.trunk!r}")
        if self.pedal_activation not in PEDAL_ACTIVATIONS:
            raise DDPGError(f"pedal_activation must be one of {PEDAL_ACTIVATIONS}, got {self.pedal_activation!r}")
        for name in ("actor_lr", "critic_lr", "ou_sigma", "ou_theta", "ou_dt", "output_init_scale", "reward_scale"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise DDPGError(f"{name} = {value} must be a finite number >= 0")
        if not 0 < self.tau <= 1 or not 0 <= self.gamma < 1:
            raise DDPGError(f"need 0 < tau <= 1 and 0 <= gamma < 1, got tau {self.tau}, gamma {self.gamma}")
        if self.batch_size < 1 or self.buffer_size < 1:
            raise DDPGError(f"batch_size and buffer_size must be >= 1, got {self.batch_size}, {self.buffer_size}")

    @property
    def pixel_actor(self) -> bool:
        return self.variant != "state-actor"

    @property
    def pixel_critic(self) -> bool:
        return self.variant == "symmetric"


#: The shared recipe: Stable-Baselines3's DDPG on Pendulum-v1 as rl-baselines3-zoo tunes it (learning rate 1e-3,
#: gamma 0.98, buffer 200,000, Gaussian noise of 0.1, here as OU noise with theta 1 and dt 1, which is Gaussian: the
#: process forgets its last value each step) with SB3's default tau (0.005), at batch 64 (the DDPG paper's, where
#: SB3's default 256 costs four times the arithmetic per update on one core).
REFERENCE_HYPER = DDPGHyper(
    variant="state-actor",
    actor_lr=1e-3,
    critic_lr=1e-3,
    tau=0.005,
    gamma=0.98,
    batch_size=64,
    buffer_size=200_000,
    ou_theta=1.0,
    ou_sigma=0.1,
    ou_dt=1.0,
    batch_norm=False,
)


#: The algorithms of the reference check (vision_rl.ddpg.reference).
ALGOS = ("ours", "ours-bn", "sb3-ddpg", "sb3-td3")


@dataclass(frozen=True)
class ReferenceRun:
    """One run of the reference check: an algorithm on a task with a seed."""

    task: str = "Pendulum-v1"
    """Gymnasium task id (Box observation and action): Pendulum-v1, MountainCarContinuous-v0."""
    algo: str = "ours"
    """ours (no batch-norm, as SB3), ours-bn (the paper's batch-norm), sb3-ddpg or sb3-td3."""
    seed: int = 0
    """Seed of the networks, the noise, the warm-up actions and the task's first reset."""
    steps: int = 20_000
    """Environment steps to train for."""
    learning_starts: int = 1_000
    """Steps of uniform random actions (plus noise) before the first update."""
    eval_every_steps: int = 1_000
    """Deterministic evaluation every this many steps (0: only at the end)."""
    eval_episodes: int = 5
    """Episodes per periodic evaluation."""
    final_eval_episodes: int = 10
    """Episodes of the evaluation at the end (the run's final return)."""
    hyper: DDPGHyper = nested(
        REFERENCE_HYPER,
        only=("actor_lr", "critic_lr", "tau", "gamma", "batch_size", "buffer_size", "ou_theta", "ou_sigma"),
        help={
            "actor_lr": "Adam step size of the actor (SB3: the same as --critic-lr).",
            "ou_theta": "OU noise mean reversion per step (1: Gaussian noise).",
            "ou_sigma": "OU noise scale, on actions in [-1, 1].",
            "buffer_size": "Replay capacity, transitions.",
        },
    )
    """Hyper-parameters of both sides (``batch_norm`` follows ``algo``; SB3 needs ``actor_lr == critic_lr``)."""

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise DDPGError(f"algo must be one of {ALGOS}, got {self.algo!r}")
        import gymnasium  # loaded with vision_rl already (its ids are registered there)

        if self.task not in gymnasium.registry:
            raise DDPGError(f"task {self.task!r} is not a registered Gymnasium id (e.g. Pendulum-v1)")
        if self.steps < 1 or self.learning_starts < 0 or self.eval_every_steps < 0:
            raise DDPGError("need steps >= 1, learning_starts >= 0 and eval_every_steps >= 0")
        if self.eval_episodes < 1 or self.final_eval_episodes < 1:
            raise DDPGError("need eval_episodes >= 1 and final_eval_episodes >= 1")
        if self.algo.startswith("sb3") and self.hyper.actor_lr != self.hyper.critic_lr:
            raise DDPGError(
                f"Stable-Baselines3 takes one learning rate for actor and critic: got actor_lr "
                f"{self.hyper.actor_lr} and critic_lr {self.hyper.critic_lr}"
            )

    @property
    def agent_hyper(self) -> DDPGHyper:
        """The hyper-parameters of the run: batch-norm only for ours-bn."""
        return dataclasses.replace(self.hyper, variant="state-actor", batch_norm=self.algo == "ours-bn")


MAX_CARS = 64


#: The environment's fields that are train-ddpg options, with the command's help for them (PixelRacingConfig's own
#: docstrings say more); the rest (control step, frames, the stuck rule) keep their defaults or follow --variant.
ENV_OPTIONS_HELP = {
    "track": "Track (the paper's Barcelona-Catalunya).",
    "car": "Car preset (the paper's Porsche 911 GT3 R).",
    "n_cars": "Cars driving at once, each alone (one frame each per step, rendered in one call).",
    "episode_s": "Episode time limit, s.",
    "image_hw_px": "The actor's frame, height and width px (the paper's 89x120).",
    "render_scale": "Render at this multiple of the frame size and box-average down (antialiasing).",
    "goal_frame": "The critic's goal: world (the racing-line point, the paper) or body (its offset from the car).",
    "racing_line": "car (the car's minimum-curvature line) or reference (the racetrack-database's race line).",
    "line_distance_alpha": "alpha of the reward V - alpha |racing-line distance| - beta crashState, (m/s) per m.",
    "crash_penalty_beta": "beta of the reward (0: the paper's simple reward).",
    "max_line_distance_m": "An episode ends farther than this from the racing line, m.",
    "terminate_on_crash": (
        "the end of an episode at a non-zero crashState (off track, a wall, spinning): it goes on, penalised by "
        "beta (the paper's alternative reward)."
    ),
    "truncate_when_stuck": (
        "A stuck car's episode ends as a truncation, not a termination: the critic bootstraps the stuck state's "
        "value, so stopping is worth what staying stopped costs, not 0 (not in the paper)."
    ),
    "start": "Episodes start at a random point (random) or on the start/finish line (line).",
    "start_skill": (
        "Episodes start at this share of the limit speed there (the built-in AI's; 0: from standstill, as a race in "
        "the game restarts)."
    ),
}

#: train-ddpg's help for the agent's hyper-parameters, where it words them otherwise than :class:`DDPGHyper`.
HYPER_OPTIONS_HELP = {
    "buffer_size": "Replay capacity, frames over all cars (100,000 89x120 frames: 3.2 GB).",
    "tau": "Soft target update.",
    "gamma": "Discount per 0.1 s step.",
    "ou_theta": "OU noise mean reversion.",
    "ou_sigma": "OU noise scale.",
    "reward_scale": "Rewards are multiplied by this in the critic's targets.",
    "pedal_activation": (
        "Output activation of the accelerate and brake keys: relu (the paper's) or sigmoid (a pedal never loses its "
        "gradient; not in the paper)."
    ),
    "channels_last": "Channels-last convolutions (faster on CPUs).",
    "trunk": (
        "The pixel actor's (and symmetric critic's) conv trunk: paper (four 2x2 stride-1 convolutions, each "
        "max-pooled) or cpu (the first two strided 2, the last two unpooled: about a tenth of the multiply-adds per "
        "update, for a 2-core CPU; not in the paper)."
    ),
}


@dataclass(frozen=True)
class TrainDDPGConfig:
    """What `train-ddpg` trains, for how long, and where it writes."""

    @staticmethod
    def check_options(options: Mapping[str, Any]) -> None:
        check_bounds(options)

    variant: str = "asymmetric"
    """asymmetric (pixel actor; critic on motion + racing line), symmetric (critic on pixels too), state-actor."""
    steps: int = 100_000
    """Transitions to train on (all cars together), including those of a resumed run."""
    train_minutes: float = 0.0
    """Also stop once the run's training time (all its sessions, evaluations excluded) reaches this many minutes
    (0: no limit): the equal wall-clock budget of a comparison of variants, trained in chunks with --resume."""
    seed: int = 0
    """Seed of the networks, the noise and the episodes' start points."""
    out: str = ""
    """Run folder (default runs/ddpg/<variant>-<track>-<car>-s<seed>)."""
    resume: bool = False
    """Continue the run in --out with its own track, car and settings (another value given for one is refused);
    --variant must name its variant."""
    force: bool = False
    """Start over in a folder that holds a run."""
    env: PixelRacingConfig = nested(
        PixelRacingConfig(),
        only=tuple(ENV_OPTIONS_HELP),
        rename={"n_cars": "cars", "start_skill": "start_speed_share"},
        help=ENV_OPTIONS_HELP,
    )
    """The environment (its ``frames`` follow --variant: :meth:`agent_configs`)."""
    hyper: DDPGHyper = nested(
        DDPGHyper(),
        only=(
            "actor_lr",
            "critic_lr",
            "tau",
            "gamma",
            "batch_size",
            "buffer_size",
            "ou_theta",
            "ou_sigma",
            "pedal_activation",
            "reward_scale",
            "channels_last",
            "trunk",
        ),
        rename={"trunk": "preset"},
        help=HYPER_OPTIONS_HELP,
    )
    """The agent's hyper-parameters (its ``variant`` is --variant's: :meth:`agent_configs`)."""
    learning_starts: int = 1_000
    """Transitions collected before the first update."""
    updates_per_step: int = 1
    """Updates after each step of all cars."""
    evaluation: EvaluationSchedule = nested(
        EvaluationSchedule(every_steps=10_000),
        prefix="eval_",
        help={
            "every_steps": (
                "Time the deterministic actor with the lap-time protocol every this many transitions (0: only at "
                "the end)."
            ),
            "seeds": "Protocol seeds per evaluation.",
            "laps": "Protocol laps per evaluation (the last is scored).",
        },
    )
    """The periodic evaluations."""
    eval_time_limit_s: float = 0.0
    """Time limit of an evaluation run, s (0: the protocol's 3 limit laps per lap)."""
    checkpoints: CheckpointSchedule = nested(
        CheckpointSchedule(every_steps=10_000),
        prefix="checkpoint_",
        help={
            "every_steps": "Save the agent and the buffer every this many transitions (0: only at the end).",
            "every_min": "Save the agent (no buffer) every this many minutes of wall-clock time (0: never).",
        },
    )
    """The periodic saves."""
    torch_threads: int = 1
    """torch threads (0: torch's default); the renderer and the simulator use the other core."""
    device: str = "auto"
    """torch device: auto (cuda when torch sees a GPU, else cpu), cpu or cuda."""
    samplers: SamplerOptions = nested(
        SamplerOptions(),
        help={
            "max_staleness": "With --workers: weight versions a sampler's actor may lag the learner's (0: synchronous)."
        },
    )
    """Sampling in Ray actors."""

    def agent_configs(self) -> tuple[DDPGHyper, PixelRacingConfig]:
        """The agent's hyper-parameters and environment: the held ones with what --variant decides (the
        hyper-parameters' variant; frames unless the actor is state-only)."""
        hyper = dataclasses.replace(self.hyper, variant=self.variant)
        return hyper, dataclasses.replace(self.env, frames=hyper.pixel_actor)


def check_bounds(o: Mapping[str, Any]) -> None:
    """One clear line for an option out of range, before anything is built or written: ``o`` holds the flat
    options (:func:`~vision_rl.config.flat_values` of a config)."""
    check_option_bounds(
        o,
        {
            "cars": Bounds(1, MAX_CARS),
            "steps": at_least(1),
            "learning_starts": at_least(0),
            "updates_per_step": at_least(0),
            "eval_every_steps": at_least(0),
            "eval_seeds": at_least(0),
            "eval_laps": at_least(1),
            "checkpoint_every_steps": at_least(0),
            "checkpoint_every_min": at_least(0),
            "train_minutes": at_least(0),
            "start_speed_share": Bounds(0, 1),
            "torch_threads": at_least(0),
            "eval_time_limit_s": at_least(0),
        },
    )
    columns = o["cars"] * (o["workers"] or 1)
    if o["buffer_size"] < 4 * columns:
        raise ValueError(f"--buffer-size {o['buffer_size']} leaves fewer than 4 rows per car for {columns} cars")
    # The replay holds a uint8 frame per row (pixel variants); a batch is read as float32 frames.
    frame_bytes = array_bytes(*o["image_hw_px"], 3, itemsize=1) if o["variant"] != "state-actor" else 0.0
    require_memory(f"--buffer-size {o['buffer_size']}", o["buffer_size"] * (frame_bytes + 100))
    require_memory(f"--batch-size {o['batch_size']}", o["batch_size"] * (4 * frame_bytes + 1000))
    if o["workers"] is not None or o["address"]:
        from vision_rl.training.distributed import check_workers

        if o["workers"] is None:
            raise ValueError(f"--address {o['address']} needs --workers: the samplers are what runs on the cluster")
        check_workers(o["workers"], o["max_staleness"], o["version_every_updates"])
