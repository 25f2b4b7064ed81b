"""train-policy's options (:class:`TrainPolicyConfig`) and their checks, and the search space of ``tune``: light (no
torch or Stable-Baselines3), so that the commands' ``--help`` answers without loading the trainer."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from vision_rl.budget import require_memory
from vision_rl.config import Bounds, at_least, check_option_bounds, nested
from vision_rl.envs.core import STEER_ACTIONS, STEER_CHANGE_PENALTY_SCALES, WALL_PENALTY_SPEEDS, RacingConfig
from vision_rl.envs.observations import ObservationKind
from vision_rl.sim.fleet import AI_CONTROL_DT_S, ai_ticks
from vision_rl.training.presets import SACOverrides, parse_hidden_units
from vision_rl.training.schedules import CheckpointSchedule, EvaluationSchedule, SamplerOptions

MAX_CARS = 1000


#: train-policy's help for the environment's options (the config's own docstrings say more).
RACING_OPTIONS_HELP = {
    "track": "Track: built-in name, random:SEED or CSV path.",
    "car": "Car preset.",
    "n_groups": "Cars sampled at once (one world, the papers' 20).",
    "episode_s": "Training episode length, s (the papers' 100 s trials).",
    "control_dt_s": (
        "Control step, s: a whole multiple of the simulator's 0.02 s (the papers' 10 Hz: 0.1). --gamma "
        "stays a discount per 0.1 s; --n-step counts control steps; c_w, c_s and c_o weigh a step (not in"
        " the papers)."
    ),
    "wall_penalty_c_w": "c_w of the reward's wall penalty.",
    "wall_penalty_speed": (
        "Speed the wall penalty squares: `end` of the step (the papers) or `impact`, the larger of the "
        "step's start and end speeds (a hit charged at the speed that hit; not in the papers)."
    ),
    "steer_change_penalty_c_s": (
        "c_s of the reward's steering-change penalty ``c_s * (change / scale)^2`` (0: the papers' reward)."
    ),
    "steer_change_penalty_scale": (
        "The steering-change penalty's scale: `limit` (the command's +-pi/6) or `usable` (the angle "
        "usable at the car's speed, +-0.07 rad at 159 km/h: a swing across it costs 4 c_s; not in the "
        "papers)."
    ),
    "off_track_penalty_c_o": (
        "c_o of a penalty c_o |v|^2 per step ending with a wheel over the edge line (not in the papers; 0: none)."
    ),
    "wall_hit_throttle_cut_s": (
        "After a wall hit, hold the throttle at zero this long, s: a hit costs time (GT Sport's "
        "wall-collision penalty; not in the papers; 0: off; evaluations never apply it)."
    ),
    "terminate_on_wall": (
        "End a training episode when the car touches a wall (a terminal step; not in the GT Sport "
        "papers). In make quick's vision stage its 8 runs finished 1 of 104 starts against 99: they "
        "stopped at the hairpin's wall with the brake held (docs/results/vision-expressway-hatchback)."
    ),
    "terminate_when_stuck": (
        "End a training episode when the car is stuck by the protocol's rule (a terminal step: the car "
        "has no reverse gear, so a stuck car earns nothing more). Otherwise it stands out the rest of its"
        " 100 s: in make quick's vision runs most of the first 60k transitions were of standing cars (not"
        " in the papers)."
    ),
    "restart_before_stuck_share": (
        "With --stuck-ends-episode: this share of training episodes starts up to --restart-before-stuck-m"
        " before a place where a car of the run recently got stuck, the rest at random points (not in the"
        " papers; 0: all random). With 0.5 make quick's vision stage lost no fewer starts over 8 seeds "
        "and lapped slower (docs/results/ vision-expressway-hatchback)."
    ),
    "restart_before_stuck_m": (
        "With --restart-before-stuck-share: the most such a start lies before the stuck place, m."
    ),
    "frame_delay_s": "Vision: frames lag the state by this long (the paper's 4 frames at 60 Hz: 0.067; 0: none).",
    "critic_state": (
        "Vision: the critic also reads the 38-D state observation, the actor the vision vector alone (an "
        "asymmetric actor-critic, as the DDPG paper's; not in the GT Sport papers). The policy drives as "
        "any vision policy."
    ),
    "steer_action": (
        "`angle`: the action is the steering command (the papers); `rate`: a change of it, up to the "
        "car's steering rate limit per step; `speed_scaled`: a share of the angles usable at the car's "
        "speed; `rate_scaled`: `rate` within that share (none in the papers)."
    ),
    "steer_change_share_of_range": (
        "`rate_scaled`: the most a step moves the steering command, as a share of the angle usable at the"
        " car's speed, where less than the rate limit (0: the rate limit alone; not in the papers)."
    ),
    "pedal_full_at": (
        "The action's throttle/brake entry at which the pedal reaches full travel (1: the papers' linear "
        "map; below 1 the deterministic policy can hold the throttle open; not in the papers)."
    ),
}


@dataclass(frozen=True)
class TrainPolicyConfig:
    """Train a SAC driving policy on the batched time-trial env (state, or vision with an encoder)."""

    @staticmethod
    def check_options(options: Mapping[str, Any]) -> None:
        check_bounds(options)

    @property
    def kind(self) -> ObservationKind:
        """What the policy observes: the frozen encoder's embedding with --encoder, else the state."""
        return ObservationKind.VISION if self.encoder else ObservationKind.STATE

    encoder: str = ""
    """Encoder ckpt.pt: vision observation (64-D embedding + 11); empty: the 38-D state observation."""
    steps: int = 1_000_000
    """Total environment steps (transitions over all cars)."""
    out: str = ""
    """Run folder (default runs/policy/<kind>-<track>-<car>-s<seed>)."""
    seed: int = 0
    """Seed of the networks, exploration and start points."""
    resume: bool = False
    """Continue the run in --out up to --steps with its own track, car, cars, encoder and SAC settings (another value
    given for one is refused), weights and buffer."""
    force: bool = False
    """Start over in an --out that holds a run."""
    racing: RacingConfig = nested(
        RacingConfig(n_groups=20),
        only=(
            "track",
            "car",
            "n_groups",
            "episode_s",
            "control_dt_s",
            "wall_penalty_c_w",
            "wall_penalty_speed",
            "steer_change_penalty_c_s",
            "steer_change_penalty_scale",
            "off_track_penalty_c_o",
            "wall_hit_throttle_cut_s",
            "terminate_on_wall",
            "terminate_when_stuck",
            "restart_before_stuck_share",
            "restart_before_stuck_m",
            "frame_delay_s",
            "critic_state",
            "steer_action",
            "steer_change_share_of_range",
            "pedal_full_at",
        ),
        rename={
            "n_groups": "cars",
            "terminate_on_wall": "wall_ends_episode",
            "terminate_when_stuck": "stuck_ends_episode",
        },
        help=RACING_OPTIONS_HELP,
    )
    """The environment the policy trains in (its observation and frame size follow --encoder)."""
    evaluation: EvaluationSchedule = nested(EvaluationSchedule(), prefix="eval_")
    """The periodic evaluations."""
    checkpoints: CheckpointSchedule = nested(CheckpointSchedule(), prefix="checkpoint_")
    """The periodic saves."""
    sac: SACOverrides = nested(SACOverrides())
    """The SAC preset and its overrides."""
    samplers: SamplerOptions = nested(SamplerOptions())
    """Sampling in Ray actors."""
    select_starts: int = 0
    """Held-out start seeds (100, 101, ...) timed at each periodic evaluation; N >= 1 keeps the weights with the
    fastest mean scored lap over them, every start finished clean (see --select-clean), in best/ (0: off)."""
    select_clean: bool = True
    """--select-starts keeps only weights whose held-out starts were all clean; --no-select-clean: all finished is
    enough (for a policy that rides the walls and sometimes loses a start, as make quick's vision policy)."""
    save_buffer: bool = True
    """Save the replay buffer with step checkpoints and on Ctrl-C (for --resume)."""
    stats_steps: int = 50
    """Vision: control steps of the feature-statistics rollout."""
    guide_steps: int = 0
    """Transitions of the built-in AI driving the cars (at the start skill) put in the replay buffer before the
    first update: demonstrations of braking, which SAC does not find here (not in the papers; 0: none)."""
    guide_bc_weight: float = 0.0
    """With --guide-steps: weight of a behaviour-cloning step of the actor on the AI's transitions after each SAC
    update (not in the papers; 0: none)."""
    guide_label_weight: float = 0.0
    """Weight of a cloning step of the actor, after each SAC update, towards the actions the built-in AI (skill
    1.0) would take at the states the policy visits, labelled as they are collected, by the samplers with --workers
    (DAgger-style; not in the papers; 0: off). At 30 in make quick's vision stage its 8 runs finished 15 of 104
    starts against 99: they swung the wheel and spun (docs/results/vision-expressway-hatchback)."""
    guide_label_steer_weight: float = 1.0
    """With --guide-label-weight: weight of the steering column in the labels' cloning loss, the pedal's being 1
    (0: the actor clones the AI's pedal alone; not in the papers). At 0 (weight 30) in make quick's vision stage its
    8 runs finished 82 of 104 starts against 99, with a third of the wall contact and slower laps; faded over the
    second half (--guide-label-fade-steps 75000) the braking went with them
    (docs/results/vision-expressway-hatchback)."""
    guide_label_fade_steps: int = 0
    """With --guide-label-weight: over the last N environment steps before --steps the labels' weight falls
    linearly to zero, so SAC alone refines the lap (not in the papers; 0: the weight stays)."""
    guide_pretrain_steps: int = 0
    """With --guide-steps: behaviour-cloning steps of the actor on the AI's transitions before the first SAC update,
    so that training starts from a policy that brakes (not in the papers; 0: none)."""
    n_step: int = 1
    """Rewards summed over N control steps before the critics bootstrap (Stable-Baselines3's n-step replay; 1: the
    papers' one-step targets)."""
    device: str = "auto"
    """Torch device: auto, cpu or cuda."""
    encoder_runtime: str = "auto"
    """Vision: `auto` (ONNX Runtime on a CPU when installed: the encoder 3-6x faster here), torch or onnxruntime."""


#: The first held-out start seed: apart from the protocol's (0, 1, 2, ...), so that the choice of weights does not
#: look at the starts they are scored from.
SELECT_SEED_BASE = 100


def check_bounds(o: Mapping[str, Any]) -> None:
    """One clear line for an option out of range, before anything is built or written: ``o`` holds the flat
    options (:func:`~vision_rl.config.flat_values` of a config)."""
    _check_ranges(o)
    _check_choices(o)
    _check_combinations(o)
    _check_memory(o)


def _check_memory(o: Mapping[str, Any]) -> None:
    """Price the replay buffer at its rows' true width: the observation and the next one (float32), action,
    reward and done; the vision vector is a 64-D embedding + 11 features, + the 38-D state with --critic-state."""
    kind = ObservationKind.VISION if o["encoder"] else ObservationKind.STATE
    width = kind.vector_dim(critic_state=bool(o["critic_state"]))
    require_memory(f"--buffer-size {o['buffer_size']}", float(o["buffer_size"]) * (2 * width + 4) * 4)


def _check_ranges(o: Mapping[str, Any]) -> None:
    check_option_bounds(
        o,
        {
            "cars": at_least(1),
            "steps": at_least(1),
            "eval_every_steps": at_least(0),
            "eval_seeds": at_least(0 if o["eval_every_steps"] == 0 else 1),
            "eval_laps": at_least(1),
            "select_starts": at_least(0),
            "checkpoint_every_steps": at_least(0),
            "checkpoint_every_min": at_least(0),
            "control_dt_s": Bounds(0, 1, low_open=True),
            "episode_s": at_least(o["control_dt_s"]),
            "wall_penalty_c_w": at_least(0),
            "steer_change_penalty_c_s": at_least(0),
            "stats_steps": at_least(1),
            "off_track_penalty_c_o": at_least(0),
            "wall_hit_throttle_cut_s": Bounds(0, 60),
            "restart_before_stuck_share": Bounds(0, 1),
            "restart_before_stuck_m": at_least(0),
            "frame_delay_s": Bounds(0, 1),
            "pedal_full_at": Bounds(0, 1, low_open=True),
            "steer_change_share_of_range": at_least(0),
            "learning_rate": at_least(0),
            "learning_rate_final": at_least(0),
            "target_entropy": Bounds(high=0),
            "batch_size": at_least(0),
            "buffer_size": at_least(0),
            "gradient_steps": at_least(0),
            "gamma": Bounds(0, 1, high_open=True),
            "n_step": Bounds(1, 100),
            "guide_steps": at_least(0),
            "guide_bc_weight": at_least(0),
            "guide_label_weight": at_least(0),
            "guide_label_fade_steps": at_least(0),
            "guide_label_steer_weight": at_least(0),
            "guide_pretrain_steps": at_least(0),
        },
    )


def _check_choices(o: Mapping[str, Any]) -> None:
    parse_hidden_units(o["hidden_units"])
    if ai_ticks(o["control_dt_s"]) is None:
        raise ValueError(
            f"--control-dt-s {o['control_dt_s']} is not a whole multiple of the simulator's "
            f"{AI_CONTROL_DT_S} s step, e.g. 0.04 (25 Hz) or 0.1 (10 Hz)"
        )
    choices = {
        "steer_action": STEER_ACTIONS,
        "wall_penalty_speed": WALL_PENALTY_SPEEDS,
        "steer_change_penalty_scale": STEER_CHANGE_PENALTY_SCALES,
    }
    for name, allowed in choices.items():
        value = o[name]
        if value not in allowed:
            raise ValueError(f"--{name.replace('_', '-')} must be one of {', '.join(allowed)}, got {value!r}")


def _check_combinations(o: Mapping[str, Any]) -> None:
    if o["steer_change_share_of_range"] > 0 and o["steer_action"] != "rate_scaled":
        raise ValueError("--steer-change-share-of-range limits rate_scaled steering: give --steer-action rate_scaled")
    if (o["guide_bc_weight"] > 0 or o["guide_pretrain_steps"] > 0) and o["guide_steps"] == 0:
        raise ValueError(
            "--guide-bc-weight and --guide-pretrain-steps clone the AI's transitions: give --guide-steps too"
        )
    if o["select_starts"] > 0 and o["eval_every_steps"] == 0:
        raise ValueError("--select-starts chooses among the periodic evaluations: give --eval-every-steps above 0")
    if not o["select_clean"] and o["select_starts"] == 0:
        raise ValueError("--no-select-clean sets the rule of --select-starts: give --select-starts N too")
    if o["select_starts"] > 0 and o["eval_seeds"] > SELECT_SEED_BASE:
        raise ValueError(
            f"--eval-seeds {o['eval_seeds']} would time the held-out starts of --select-starts, which "
            f"begin at seed {SELECT_SEED_BASE}: give at most {SELECT_SEED_BASE}"
        )
    shaping = [
        name
        for name, given in (
            ("--guide-label-fade-steps", o["guide_label_fade_steps"] > 0),
            ("--guide-label-steer-weight", o["guide_label_steer_weight"] != 1),
        )
        if given
    ]
    if shaping and o["guide_label_weight"] == 0:
        raise ValueError(f"{shaping[0]} shapes the labels' cloning: give --guide-label-weight too")
    if o["restart_before_stuck_share"] > 0 and not o["stuck_ends_episode"]:
        raise ValueError("--restart-before-stuck-share starts episodes before stuck ends: give --stuck-ends-episode")
    if o["frame_delay_s"] > 0 and not o["encoder"]:
        raise ValueError("--frame-delay-s delays the vision frames: give --encoder (the state observation has none)")
    if o["critic_state"] and not o["encoder"]:
        raise ValueError("--critic-state gives a vision policy's critic the state observation: give --encoder")
    if o["workers"] is not None or o["address"]:
        from vision_rl.training.distributed import check_workers

        if o["workers"] is None:
            raise ValueError(f"--address {o['address']} needs --workers: the samplers are what runs on the cluster")
        check_workers(o["workers"], o["max_staleness"], o["version_every_updates"])
        if o["n_step"] > 1 and o["workers"] > 1:
            # The learner's buffer interleaves the samplers' vector steps, so a column is not one car's time line.
            raise ValueError(f"--n-step {o['n_step']} needs one car's steps in a row: use --workers 1 or leave it out")
    # The world holds every car's state and, for vision, renders every car's frame each step; 1,000 cars is far
    # beyond the papers' 20 and what one process can step at a useful rate.
    if o["cars"] > MAX_CARS:
        raise ValueError(f"--cars {o['cars']} is more than {MAX_CARS} cars in one world")


@dataclass(frozen=True)
class Param:
    """One searched option of :class:`TrainPolicyConfig`."""

    kind: str
    """``log``: log-uniform between the two values; ``choice``: one of the values."""
    values: tuple[Any, ...]
    why: str
    """What it trades (the levers of issue 16's learning per CPU-second)."""


SEARCH_SPACE: dict[str, Param] = {
    "learning_rate": Param("log", (1e-4, 3e-3), "Adam step size of actor, critics and entropy coefficient"),
    "batch_size": Param("choice", (128, 256, 512), "transitions per update: 63 updates/s at 256, 42 at 512 here"),
    "gradient_steps": Param("choice", (1, 2, 4), "updates per vector step: learning per sample against samples/s"),
    "gamma": Param("choice", (0.98, 0.99, 0.995), "discount per 0.1 s: horizon 5, 10 or 20 s"),
    "hidden_units": Param("choice", ("128,128", "256,256", "256,256,256"), "network width and depth"),
    "n_step": Param("choice", (1, 3, 5), "n-step returns: reward reaches the critics n steps sooner"),
    "episode_s": Param("choice", (50.0, 100.0, 200.0), "episode length: how often a car restarts at random"),
    "wall_penalty_c_w": Param("log", (0.002, 0.02), "the wall penalty's weight (the papers: 0.005)"),
    "off_track_penalty_c_o": Param("choice", (0.0, 0.002, 0.005), "a penalty for running wide of the edge line"),
    "steer_change_penalty_c_s": Param("choice", (0.0, 0.1, 0.5), "action smoothing by a steering-change penalty"),
    "steer_action": Param("choice", STEER_ACTIONS, "what the steering action means"),
}
