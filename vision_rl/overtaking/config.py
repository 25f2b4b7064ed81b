"""The overtaking paper's commands' options (train-overtaking, train-baseline, table3, play, record-demos) and
their checks: light (no torch or Stable-Baselines3), so that the commands' ``--help`` answers without loading a
trainer."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from vision_rl.budget import require_memory
from vision_rl.config import Bounds, above, at_least, check_option_bounds, nested
from vision_rl.envs.core import RacingConfig
from vision_rl.envs.observations import ObservationKind
from vision_rl.sim.ai_driver import DEFAULT_SKILL
from vision_rl.training.presets import PRESETS, SACOverrides
from vision_rl.training.schedules import CheckpointSchedule, EvaluationSchedule, SamplerOptions

#: The 96-D observation of the overtaking paper (72-beam lidar).
OBSERVATION = "overtaking"
#: The single-car race of Table III: the curriculum's stage 1 (alone, Eq. 1).
SCENARIO = "stage1"
AGENTS = ("1", "2", "3", "standard")
MAX_CARS = 1000


@dataclass(frozen=True)
class CurriculumBudget:
    """Environment steps (transitions over all cars) of each stage."""

    stage1_max_steps: int
    """Stage 1 ends here at the latest (earlier when the lap-time criterion is met)."""
    stage2_steps: int
    """Steps of stage 2."""
    stage3_steps: int
    """Steps of stage 3 (Agents 2 and 3)."""


#: The paper gives Table II (the SAC recipe of ``train.PRESETS``) but no step counts per stage: the budgets are
#: ours. ``cpu``: train-policy's cpu recipe learned to lap the expressway within 200k-300k steps at about 1,100
#: transitions/s on the shared 2 cores, so 1M steps per stage keeps each agent within the 2-hour target.
BUDGETS: dict[str, CurriculumBudget] = {
    "paper": CurriculumBudget(2_000_000, 2_000_000, 2_000_000),
    "cpu": CurriculumBudget(1_000_000, 1_000_000, 1_000_000),
}


@dataclass(frozen=True)
class TrainOvertakingConfig:
    """Curriculum SAC (stages 1-3, Agents 1-3) or standard SAC on the overtaking task."""

    @staticmethod
    def check_options(options: Mapping[str, Any]) -> None:
        check_overtaking_ranges(options)
        check_buffer_memory(options, ("buffer_size", "stage3_buffer_size"))

    agent: str = "1"
    """1 (stages 1-2), 2 (1-3, c 0.005 in stage 3), 3 (1-3, c 0.01 in stage 3) or standard (Eq. 2 from scratch)."""
    racing: RacingConfig = nested(
        RacingConfig(car="tt_cup", n_groups=20, observation=OBSERVATION),
        only=("track", "car", "n_groups", "episode_s", "overtake_gain_c_r", "detection_range_c_d_m"),
        rename={"n_groups": "cars"},
        help={
            "track": "Track: built-in name, random:SEED or CSV path.",
            "car": "Car preset (the paper's Audi TT Cup: tt_cup).",
            "n_groups": "Ego cars in the one world, each with its own opponents (the paper's 20).",
            "episode_s": "Training episode length, s (the paper's 1,000 steps at 10 Hz).",
            "overtake_gain_c_r": "c_r of Eq. 2 (the paper gives none).",
            "detection_range_c_d_m": "c_d of Eq. 2, m (the paper gives none).",
        },
    )
    """The racing every stage builds on (each stage sets its scenario and penalties)."""
    evaluation: EvaluationSchedule = nested(
        EvaluationSchedule(),
        prefix="eval_",
        help={
            "every_steps": "Evaluate every N cumulative steps (0: off; stage 1 then runs to its cap).",
            "seeds": "Start seeds of the protocol lap of each evaluation.",
            "laps": "Laps of that protocol run (the last is scored).",
        },
    )
    """The periodic evaluations."""
    checkpoints: CheckpointSchedule = nested(
        CheckpointSchedule(),
        prefix="checkpoint_",
        help={
            "every_steps": "Save weights and buffer every N steps (0: off).",
            "every_min": "Save weights, optimisers and counters every N minutes (0: off).",
        },
    )
    """The periodic saves."""
    sac: SACOverrides = nested(
        SACOverrides(),
        only=("preset", "learning_rate", "batch_size", "buffer_size", "learning_starts", "gradient_steps"),
        help={
            "preset": "`paper` (Table II) or `cpu` (learns on 2 cores); also sets the stage budgets.",
            "buffer_size": "Override the preset's buffer size of stages 1-2 and standard SAC (0: preset).",
        },
    )
    """The SAC preset (it also sets the stage budgets) and its overrides."""
    samplers: SamplerOptions = nested(
        SamplerOptions(),
        help={
            "workers": "Sampler actors (Ray), each a world of --cars ego cars in its own process, while this process "
            "learns; leave it out to sample in this process."
        },
    )
    """Sampling in Ray actors."""
    out: str = ""
    """Run folder shared by Agents 1-3 and standard SAC of one seed (default runs/overtaking/<track>-<car>-s<seed>)."""
    seed: int = 0
    """Seed of the networks, exploration and start points."""
    force: bool = False
    """Delete the run folder and start over."""
    stage1_max_steps: int = 0
    """Stage 1's step cap (0: the preset's)."""
    stage1_margin: float = 0.05
    """Stage 1 ends once the protocol lap time is within this share of the built-in AI's."""
    stage2_steps: int = 0
    """Steps of stage 2 (0: the preset's)."""
    stage3_steps: int = 0
    """Steps of stage 3 (0: the preset's)."""
    stage3_buffer_size: int = 0
    """FIFO buffer of stage 3, transitions (0: half of --stage3-steps, so older data is gone mid-stage)."""
    stage1_from: str = ""
    """A run folder whose finished stage 1 this one starts from (hard-linked in when this one has none): the c_r
    ablation, since racing alone does not depend on c_r or c_d; every other shared setting must agree."""
    standard_steps: int = 0
    """Steps of standard SAC (0: stage-1 cap + stage 2 + stage 3, the curriculum's budget)."""
    eval_time_limit_s: float = 0.0
    """Time limit of that protocol run, s (0: the protocol's)."""
    eval_episodes: int = 4
    """Stage-2 episodes of the overtaking return of each evaluation (0: none)."""
    eval_episode_s: float = 0.0
    """Length of those episodes, s (0: --episode-s)."""
    device: str = "auto"
    """Torch device: auto, cpu or cuda."""


#: Bytes of a replay row of the 96-D observation: it and the next one, action, reward and done, as float32.
ROW_BYTES = (2 * ObservationKind(OBSERVATION).vector_dim() + 4) * 4


def check_buffer_memory(o: Mapping[str, Any], names: tuple[str, ...]) -> None:
    """Price the replay buffers ``names`` of the flat options ``o`` against the memory budget."""
    for name in names:
        require_memory(f"--{name.replace('_', '-')} {o[name]}", float(o[name]) * ROW_BYTES)


def check_overtaking_ranges(o: Mapping[str, Any]) -> None:
    """train-overtaking's flat options' values in their own words (:func:`~vision_rl.config.flat_values`)."""
    if o["agent"] not in AGENTS:
        raise ValueError(f"--agent must be one of {', '.join(AGENTS)}, got {o['agent']!r}")
    if o["preset"] not in PRESETS or o["preset"] not in BUDGETS:
        raise ValueError(f"--preset must be one of {sorted(BUDGETS)}, got {o['preset']!r}")
    check_option_bounds(
        o,
        {
            "cars": Bounds(1, MAX_CARS),
            "stage1_max_steps": at_least(0),
            "stage1_margin": at_least(0),
            "stage2_steps": at_least(0),
            "stage3_steps": at_least(0),
            "stage3_buffer_size": at_least(0),
            "standard_steps": at_least(0),
            "episode_s": above(0),
            "overtake_gain_c_r": at_least(0),
            "detection_range_c_d_m": above(0),
            "eval_every_steps": at_least(0),
            "eval_seeds": at_least(1),
            "eval_laps": at_least(1),
            "eval_time_limit_s": at_least(0),
            "eval_episodes": at_least(0),
            "eval_episode_s": at_least(0),
            "checkpoint_every_steps": at_least(0),
            "checkpoint_every_min": at_least(0),
            "learning_rate": at_least(0),
            "batch_size": at_least(0),
            "buffer_size": at_least(0),
            "gradient_steps": at_least(0),
        },
    )


def race_config(track: str, car: str, n_groups: int = 1, episode_s: float = 100.0) -> RacingConfig:
    """The single-car race of Table III: ``stage1`` (alone), the 96-D observation, Eq. 1 with ``c_w`` 0.005."""
    return RacingConfig(
        track=track,
        car=car,
        observation=OBSERVATION,
        scenario=SCENARIO,
        n_groups=n_groups,
        episode_s=episode_s,
        wall_penalty_c_w=0.005,
    )


#: The Table III algorithms (each trained by its own module; :mod:`.baselines` sends each to its learner).
ALGO_NAMES = ("bc", "gail", "td3", "sac", "dreamer")


@dataclass(frozen=True)
class TrainBaselineConfig:
    """A Table III baseline (bc, gail, td3, sac or dreamer) on the single-car race, MLP 2 x 256, the 96-D
    observation."""

    @staticmethod
    def check_options(options: Mapping[str, Any]) -> None:
        check_baseline_ranges(options)
        check_buffer_memory(options, ("buffer_size",))

    algo: str = "bc"
    """bc, gail, td3, sac or dreamer (the PlaNet row)."""
    steps: int = 0
    """bc: cap on gradient updates (0: 200k; it stops at convergence); online: environment steps over all cars
    (0: our SAC stage 1's budget, 1M)."""
    seed: int = 0
    """Seed of the networks, exploration, start points and the bc split."""
    demos: str = "runs/demos/ai.npz"
    """Demonstrations (record-demos) for bc and gail."""
    racing: RacingConfig = nested(
        race_config("expressway", "tt_cup", n_groups=20),
        only=("track", "car", "n_groups", "episode_s"),
        rename={"n_groups": "cars"},
        help={
            "track": "Track: built-in name, random:SEED or CSV path (the demonstrations' own).",
            "car": "Car preset (the paper's Audi TT Cup: tt_cup).",
            "n_groups": "Online algorithms: cars sampled at once in one world (the paper's 20).",
            "episode_s": "Training episode length, s (1,000 steps at 10 Hz).",
        },
    )
    """The single-car race of Table III (its scenario, observation and reward are the paper's)."""
    sac: SACOverrides = nested(
        SACOverrides(),
        only=("preset", "learning_rate", "batch_size", "buffer_size", "learning_starts"),
        help={
            "preset": "Online recipe: cpu (our SAC stage 1's) or paper (Table II).",
            "learning_rate": "Override the preset's (online) or bc's 1e-3 learning rate (0: keep).",
            "batch_size": "Override the preset's (online) or bc's 256 batch size (0: keep).",
            "buffer_size": "Override the preset's replay buffer size (0: keep).",
            "learning_starts": "Override the preset's random start steps (-1: keep).",
        },
    )
    """The online recipe: a SAC preset and its overrides (bc reads the learning rate and batch size)."""
    evaluation: EvaluationSchedule = nested(
        EvaluationSchedule(),
        prefix="eval_",
        help={
            "every_steps": "Online: evaluate on the lap-time protocol every N steps (0: off).",
            "seeds": "Start seeds of each periodic evaluation.",
            "laps": "Laps of each periodic evaluation (the last is scored).",
        },
    )
    """The periodic evaluations of the online algorithms."""
    checkpoints: CheckpointSchedule = nested(
        CheckpointSchedule(),
        prefix="checkpoint_",
        help={
            "every_steps": "Online: save weights and replay buffer every N steps (0: off).",
            "every_min": "Online: save weights, optimisers and counters every N minutes (0: off).",
        },
    )
    """The periodic saves of the online algorithms."""
    out: str = ""
    """Run folder (default runs/baselines/<algo>-<track>-<car>-s<seed>)."""
    force: bool = False
    """Delete the run folder and start over."""
    eval_time_limit_s: float = 0.0
    """Time limit of each periodic evaluation, s (0: the protocol's)."""
    bc_patience: int = 10
    """bc: stop after this many epochs without a better held-out error."""
    bc_min_improvement: float = 0.01
    """bc: an epoch is better when its held-out error is below (1 - this) x the best so far."""
    bc_max_epochs: int = 500
    """bc: cap on epochs."""
    bc_smooth_steps: int = 2
    """bc: the steering label is the mean of the demonstrator's last N labels in its episode (1: as recorded); the
    AI held at 10 Hz alternates its steering from step to step, which the wheel filters out."""
    gail_disc_every_steps: int = 1_000
    """gail: discriminator updates every N transitions."""
    gail_disc_updates: int = 10
    """gail: discriminator gradient steps each time."""
    gail_disc_batch: int = 256
    """gail: expert and learner pairs per discriminator step (each)."""
    gail_disc_lr: float = 3e-4
    """gail: discriminator learning rate."""
    td3_noise: float = 0.1
    """td3: std of the Gaussian exploration noise, as a share of each action's half range."""
    dreamer_train_every_steps: int = 20
    """dreamer: transitions (over all cars) per update of the world model, actor and value (20: SAC's number of
    updates, Table III's PlaNet row)."""
    dreamer_sequence_steps: int = 32
    """dreamer: control steps per training sequence."""
    device: str = "auto"
    """Torch device: auto, cpu or cuda."""


def check_baseline_ranges(o: Mapping[str, Any]) -> None:
    """train-baseline's flat options' values in their own words (:func:`~vision_rl.config.flat_values`)."""
    if o["algo"] not in ALGO_NAMES:
        hint = "; PlaNet's row is trained as its successor, --algo dreamer" if o["algo"].lower() == "planet" else ""
        raise ValueError(f"--algo must be one of {', '.join(ALGO_NAMES)}, got {o['algo']!r}{hint}")
    if o["preset"] not in PRESETS:
        raise ValueError(f"--preset must be one of {sorted(PRESETS)}, got {o['preset']!r}")
    check_option_bounds(
        o,
        {
            "steps": at_least(0),
            "cars": Bounds(1, 1000),
            "episode_s": at_least(0.1),
            "learning_rate": at_least(0),
            "batch_size": at_least(0),
            "buffer_size": at_least(0),
            "eval_every_steps": at_least(0),
            "eval_seeds": at_least(1),
            "eval_laps": at_least(1),
            "eval_time_limit_s": at_least(0),
            "checkpoint_every_steps": at_least(0),
            "checkpoint_every_min": at_least(0),
            "bc_patience": at_least(1),
            "bc_min_improvement": Bounds(0, 1, high_open=True),
            "bc_max_epochs": at_least(1),
            "bc_smooth_steps": Bounds(1, 100),
            "gail_disc_every_steps": at_least(1),
            "gail_disc_updates": at_least(0),
            "gail_disc_batch": at_least(1),
            "gail_disc_lr": above(0),
            "td3_noise": at_least(0),
            "dreamer_train_every_steps": at_least(1),
            "dreamer_sequence_steps": at_least(2),
        },
    )


@dataclass(frozen=True)
class Table3Config:
    """Table III of the overtaking paper: the built-in AI and the trained baselines through the lap-time protocol."""

    runs: str = ""
    """Comma-separated run folders of train-baseline (or train-overtaking stage1 folders as SAC); empty: every run
    under --runs-root."""
    runs_root: str = "runs/baselines"
    """Where to look for runs when --runs is empty."""
    track: str = "expressway"
    """Track of the table (runs of another track are refused when given, skipped when found)."""
    car: str = "tt_cup"
    """Car of the table."""
    seeds: int = 3
    """Protocol start seeds per row (the best scored lap is the row's)."""
    laps: int = 2
    """Protocol laps (the last is scored)."""
    time_limit_s: float = 0.0
    """Protocol time limit, s (0: the protocol's, 3 x the limit lap per lap)."""
    demonstrator: bool = True
    """Add the imitation baselines' demonstrator (the AI held at 10 Hz) as an extra row."""
    keep: str = ""
    """A table3 record (its --json) whose rows stand in for the algorithms with no run here (runs gone, or not
    timed again), each marked as kept; it must be of the same track, car and protocol."""


ALIAS_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,31}")


@dataclass(frozen=True)
class PlayConfig:
    """Drive the protocol's laps yourself, with keyboard or gamepad, in a pygame window."""

    name: str = ""
    """Your alias for the leaderboard row "human (alias)" (letters, digits, _ . -; up to 32) (required)."""
    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "hatchback"
    """Car preset."""
    laps: int = 2
    """Laps to drive; the protocol scores the last."""
    seed: int = 0
    """Protocol start seed (the rolling start's small offset and speed jitter)."""
    camera: str = "chase"
    """chase (behind and above the car) or hood (the driver's view the vision agents learn from)."""
    input: str = "keyboard"
    """keyboard (arrows or WASD) or gamepad (left stick, triggers)."""
    window_hw_px: tuple[int, int] = (480, 800)
    """Window height and width, px."""
    time_limit_s: float = 0.0
    """End the run after this many simulated seconds (0: the protocol's, 3 x the limit lap time per lap)."""
    realtime: bool = True
    """Run at the wall clock's pace (off only for scripted runs)."""
    runs: str = "runs"
    """Folder of the runs; the row goes to RUNS/human/ALIAS-TRACK-CAR/evaluation.json."""
    demos: str = ""
    """Demonstrations file (default: demos.npz beside the row)."""
    setting: str = ""
    """Empty: the time trial. A or B: the overtaking paper's setting (five AI cars 50 / 200 m ahead), --setting-runs
    runs whose best is the human reference of evaluate-overtaking --human (the paper's car: --car tt_cup)."""
    setting_runs: int = 2
    """Runs of --setting (the paper's human drove 2); run k meets the opponents of every agent's run --seed + k."""


@dataclass(frozen=True)
class RecordDemosConfig:
    """Record the built-in AI's demonstrations of the single-car race (96-D observation, Eq. 1)."""

    driver: str = "ai"
    """Who demonstrates: ai (the built-in AI, expressed in the environment's 10 Hz action space)."""
    laps: float = 5.0
    """Record until the cars together have driven this many laps of track progress."""
    out: str = "runs/demos/ai.npz"
    """The demonstrations file (.npz, no pickle)."""
    track: str = "expressway"
    """Track: built-in name, random:SEED or CSV path."""
    car: str = "tt_cup"
    """Car preset (the paper's Audi TT Cup: tt_cup)."""
    cars: int = 4
    """Cars recorded at once (one world, each alone in its own group)."""
    seed: int = 0
    """Seed of the episodes' start points: group 0's first episode is reset(seed=seed)'s."""
    episode_s: float = 100.0
    """Episode length, s (the training environments' 100 s: each episode starts at a new random point)."""
    skill: float = field(default=DEFAULT_SKILL, metadata={"max": 1.0})
    """The demonstrator's share of the reference speed (the built-in AI's default)."""
    noise: float = 0.0
    """Std of Gaussian noise added to the applied action, as a share of each action's half range (steering pi/6,
    omega 1); the label stays the demonstrator's (noise injection: it shows how the AI recovers)."""
    learner: str = ""
    """A bc run (train-baseline) that drives while the AI labels every step (DAgger: the learner's own mistakes,
    with the AI's correction); empty: the AI drives."""
    include: str = ""
    """A demonstrations file whose transitions come first in --out (DAgger's aggregate of earlier rounds)."""
