"""The batched racing core behind every environment: M groups (an ego car and K built-in AI opponents each) in
one World, stepped together with no Python loop over cars.

Group g holds cars ``g * (K + 1)`` (its ego) to ``g * (K + 1) + K``; groups never touch each other, so 20
time-trial cars are 20 groups of one. The gymnasium environments (one group) and the vector environments (M
groups, same-step autoreset) are thin layers over :class:`RacingCore`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from vision_rl.budget import DURATION_MAX_S
from vision_rl.envs import observations as obs_lib
from vision_rl.envs.observer import Observer
from vision_rl.envs.rewards import (
    off_track_penalty,
    overtaking_reward,
    racing_reward,
    steering_change_penalty,
    wall_penalty_speed_mps,
    wrapped_gap_m,
)
from vision_rl.sim.ai_driver import DEFAULT_SKILL, OPPONENT_SKILL_RANGE, AIDriver, Disruptor
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.fleet import AI_CONTROL_DT_S, AIFleet, StuckDetector, ai_ticks
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD, GRAVITY_MPS2, get_preset
from vision_rl.sim.world import StepEvents, World, WorldConfig

#: Scenario name -> (opponents per group, spacing between consecutive cars along the track in m).
SCENARIOS: dict[str, tuple[int, float]] = {
    "time_trial": (0, 0.0),
    "stage1": (0, 0.0),  # the curriculum's first stage: racing alone (overtaking paper, section III-C)
    "stage2": (1, 200.0),  # one built-in AI car 200 m ahead (section III-C)
    "setting_a": (5, 50.0),  # evaluation: five opponents ahead, 50 m apart (section IV-C)
    "setting_b": (5, 200.0),  # evaluation: five opponents ahead, 200 m apart
}
#: Seed of the rollout that the normalisation statistics are sampled from: one set of numbers per configuration.
STATS_SEED = 12345
#: Groups of the world whose disrupted-AI drive gives the normalisation statistics (the papers' 20 cars).
STATS_GROUPS = 20
#: Stuck points an environment keeps for ``RacingConfig.restart_before_stuck_share``: the most recent, so the starts
#: follow where the policy in training fails now rather than where its first random actions did.
STUCK_POINTS_KEPT = 32


#: How the first action entry steers (:func:`steering_command`).
STEER_ACTIONS: tuple[str, ...] = ("angle", "rate", "speed_scaled", "rate_scaled")
#: Speeds the wall penalty may square (see :func:`vision_rl.envs.rewards.wall_penalty_speed_mps`).
WALL_PENALTY_SPEEDS: tuple[str, ...] = ("end", "impact")
#: What the steering-change penalty measures a change against (``RacingConfig.steer_change_penalty_scale``).
STEER_CHANGE_PENALTY_SCALES: tuple[str, ...] = ("limit", "usable")
#: ``speed_scaled``: the command's range at speed v is this many times ``wheelbase * g / v^2``, the angle a
#: neutral-steering car needs for 1 g. Chosen to cover the built-in AI at skill 1.0 on expressway and technical
#: (hatchback, L = 2.566 m): its largest command was 0.072 rad at 40-45 m/s (the range at 42.5 m/s: 0.084 rad) and
#: 0.155 rad at 25-30 m/s (range at 27.5 m/s: 0.20); below 17 m/s (61 km/h) the range is the full pi/6.
SPEED_SCALED_STEER_G_MULTIPLE = 6.0


def usable_steer_rad(speed_mps: np.ndarray, wheelbase_m: float) -> np.ndarray:
    """The ``speed_scaled`` range at a speed: ``min(pi/6, k * wheelbase_m * g / speed^2)``, rad."""
    speed_sq = np.maximum(np.square(np.asarray(speed_mps, dtype=np.float64)), 1e-6)
    one_g_rad = wheelbase_m * GRAVITY_MPS2 / speed_sq  # in this order: trained policies' laps repeat bit for bit
    return np.minimum(ACTION_STEER_LIMIT_RAD, SPEED_SCALED_STEER_G_MULTIPLE * one_g_rad)


def steering_command(
    action_steer: np.ndarray,
    previous_command_rad: np.ndarray,
    steer_action: str,
    max_change_rad: float,
    speed_mps: np.ndarray | None = None,
    wheelbase_m: float = 0.0,
    change_share_of_range: float = 0.0,
) -> np.ndarray:
    """The steering command (rad) an action's first entry gives; every mode clips it to +-pi/6.

    - ``angle``: the entry itself (the papers).
    - ``rate``: the previous command plus ``entry / (pi/6)`` (clipped to [-1, 1]) times ``max_change_rad``. The wheel
      cannot follow a command faster than the car's steering rate limit (hatchback 1.2 rad/s, 0.12 rad per 0.1 s
      step), so an angle command far from the wheel only sets the direction it moves in, and the wheel's angle is
      hidden from an observation that holds the previous command. With ``rate`` and ``max_change_rad`` the car's
      limit over one control step, the observed previous command is the wheel's angle up to the actuator's lag.
    - ``speed_scaled``: ``entry / (pi/6)`` of ``min(pi/6, k * wheelbase_m * g / speed_mps^2)``,
      ``k = SPEED_SCALED_STEER_G_MULTIPLE``: the whole action range is spent on the angles a car can use at its
      speed (as games scale a pad's steering with speed). At 160 km/h the papers' action asks for up to 0.52 rad
      where the built-in AI never uses more than 0.07: one exploration step or one swing of a bang-bang policy
      then spins the car.
    - ``rate_scaled``: ``rate`` with the command clipped to the ``speed_scaled`` range: the wheel's angle stays
      observable and the wheel never leaves the angles usable at the car's speed. With ``change_share_of_range``
      > 0, one step moves the command by at most that share of the usable angle where that is less than
      ``max_change_rad`` (:func:`rate_step_rad`).
    """
    action_steer = np.asarray(action_steer, dtype=np.float64)
    share = np.clip(action_steer / ACTION_STEER_LIMIT_RAD, -1.0, 1.0)
    if steer_action == "angle":
        return np.clip(action_steer, -ACTION_STEER_LIMIT_RAD, ACTION_STEER_LIMIT_RAD)
    if steer_action == "rate":
        return np.clip(previous_command_rad + share * max_change_rad, -ACTION_STEER_LIMIT_RAD, ACTION_STEER_LIMIT_RAD)
    usable_rad = usable_steer_rad(speed_mps, wheelbase_m)
    if steer_action == "speed_scaled":
        return share * usable_rad
    step_rad = rate_step_rad(max_change_rad, usable_rad, change_share_of_range)
    return np.clip(previous_command_rad + share * step_rad, -usable_rad, usable_rad)


def rate_step_rad(max_change_rad: float, usable_rad: np.ndarray, change_share_of_range: float) -> np.ndarray | float:
    """The most a ``rate_scaled`` command moves in one step, rad: the car's rate limit over the step or, with
    ``change_share_of_range`` > 0, that share of the angle usable at the car's speed where it is less."""
    if change_share_of_range <= 0:
        return max_change_rad
    return np.minimum(max_change_rad, change_share_of_range * usable_rad)


def action_for_command(
    command_rad: np.ndarray,
    previous_command_rad: np.ndarray,
    steer_action: str,
    max_change_rad: float,
    speed_mps: np.ndarray,
    wheelbase_m: float,
    change_share_of_range: float = 0.0,
) -> np.ndarray:
    """The action's first entry that asks :func:`steering_command` for ``command_rad`` (the nearest one where the
    mode cannot reach it in one step: a change beyond the rate limit, an angle beyond the speed's range)."""
    command_rad = np.asarray(command_rad, dtype=np.float64)
    if steer_action == "angle":
        return np.clip(command_rad, -ACTION_STEER_LIMIT_RAD, ACTION_STEER_LIMIT_RAD)
    if steer_action == "rate":
        share = (command_rad - previous_command_rad) / max_change_rad
    elif steer_action == "rate_scaled":
        usable_rad = usable_steer_rad(speed_mps, wheelbase_m)
        share = (command_rad - previous_command_rad) / rate_step_rad(max_change_rad, usable_rad, change_share_of_range)
    else:
        share = command_rad / usable_steer_rad(speed_mps, wheelbase_m)
    return np.clip(share, -1.0, 1.0) * ACTION_STEER_LIMIT_RAD


def pedal_command(action_pedal: np.ndarray, pedal_full_at: float) -> np.ndarray:
    """The throttle/brake command omega in [-1, 1] an action's second entry gives: ``entry / pedal_full_at``,
    clipped, so any entry beyond ``+-pedal_full_at`` asks for full travel (1: the papers' map)."""
    return np.clip(np.asarray(action_pedal, dtype=np.float64) / pedal_full_at, -1.0, 1.0)


def action_for_pedal(omega: np.ndarray, pedal_full_at: float) -> np.ndarray:
    """The action's second entry that asks :func:`pedal_command` for ``omega``. Full travel asks for the end of the
    action's range, where a tanh policy's mean lies well inside the saturated band, rather than for its edge."""
    omega = np.clip(np.asarray(omega, dtype=np.float64), -1.0, 1.0)
    return np.where(np.abs(omega) >= 1.0, omega, omega * pedal_full_at)


@dataclass(frozen=True)
class RacingConfig:
    """Everything that defines an environment; stored with policies so evaluation rebuilds the same one."""

    track: str = "expressway"
    """Built-in track name, ``random:SEED`` or a racetrack-database CSV path."""
    car: str = "hatchback"
    """Car preset of every car (hatchback, tt_cup, gt3)."""
    observation: str = "state"
    """``state`` (38-D privileged), ``vision`` (frame + 11 features) or ``overtaking`` (96-D lidar)."""
    scenario: str = "time_trial"
    """time_trial / stage1 (alone), stage2 (one AI 200 m ahead), setting_a / setting_b (five AIs, 50 / 200 m)."""
    n_groups: int = 1
    """Independent groups (ego cars) in the world; the vector environments default to 20 as in the papers."""
    control_dt_s: float = 0.1
    """Control step, s (10 Hz in both GT Sport papers)."""
    episode_s: float = 100.0
    """Episode length, s: the papers' 100 s trials (1,000 steps at 10 Hz); the end is a truncation."""
    wall_penalty_c_w: float = 0.005
    """c_w of the racing reward (overtaking paper, section IV-B: 0.005)."""
    wall_penalty_speed: str = "end"
    """Speed the wall penalty squares: ``end`` of the step (the papers) or ``impact``, the larger of the step's start
    and end speeds, so a hit is charged at the speed that hit (:func:`vision_rl.envs.rewards.wall_penalty_speed_mps`;
    not in the papers)."""
    wall_hit_throttle_cut_s: float = 0.0
    """After a control step in which the ego's wall contact begins, its throttle is held at zero (the brake still
    works) for this long, s: a hit costs time, as GT Sport's wall-collision penalty slows a car down, where a reward
    penalty alone left the wall a cheaper brake than the brakes (docs/results/state-expressway-hatchback-clean; not
    in the papers; 0: off). The observation does not show the cut; the lap-time protocol never applies it."""
    frame_delay_s: float = 0.0
    """Vision: frames show the world this long before the state (the paper's 4 frames at 60 Hz: 0.067; 0: none);
    the dedicated features are not delayed."""
    steer_change_penalty_c_s: float = 0.0
    """c_s of a penalty ``c_s * (change of the steering command / scale)^2`` per step, against bang-bang
    steering (not in the papers; 0: their reward)."""
    steer_change_penalty_scale: str = "limit"
    """The steering-change penalty's scale: ``limit``, the command's +-pi/6, or ``usable``, the angle usable at the
    car's speed when the step starts (:func:`usable_steer_rad`). At 159 km/h the hatchback may use +-0.07 rad, so a
    swing between the ends of that range, which spun ``make quick``'s vision policies into the chicane's wall
    (docs/results/vision-expressway-hatchback), costs ``0.07 c_s`` against ``limit`` and ``4 c_s`` against
    ``usable``, while at low speed the two agree."""
    off_track_penalty_c_o: float = 0.0
    """c_o of a penalty ``c_o * |v|^2`` per step that ends with the side of the ego's body beyond the painted edge
    line (a wheel on the kerb; :func:`vision_rl.envs.rewards.off_track_penalty`; not in the papers; 0: their
    reward)."""
    steer_action: str = "angle"
    """``angle``: the action's first entry is the steering command, rad (the papers); ``rate``: a change of the
    command, up to what the car's steering rate limit moves the wheel in one control step; ``speed_scaled``: a share
    of the angles a car can use at its speed; ``rate_scaled``: ``rate`` within that range (see :func:`steering_command`;
    none in the papers)."""
    steer_change_share_of_range: float = 0.0
    """``rate_scaled``: the most one control step may move the steering command, as a share of the angle usable at
    the car's speed, where that is less than the car's rate limit (:func:`rate_step_rad`; 0: the rate limit alone;
    not in the papers). At 157 km/h the hatchback may use +-0.080 rad and its rate limit moves the wheel 0.12 rad in
    a 0.1 s step, so one full action crosses most of the range: the clean state policies swing between its ends
    every 0.3 s on the straights (+-0.09 rad at 145 km/h) and, on some seeds, into the wall of the 157 km/h
    chicane. With 0.5 a full action there moves the wheel a quarter of the range (docs/results/
    state-expressway-hatchback-clean)."""
    pedal_full_at: float = 1.0
    """The action's second entry at which throttle (or, negative, the brake) reaches full travel: omega =
    ``entry / pedal_full_at``, clipped (:func:`pedal_command`; 1: the papers' linear map). A tanh-squashed SAC
    policy's deterministic action comes close to +-1 but not to it: the clean state policies held 0.96-0.98 on the
    straights, 6-9 km/h slower than the built-in AI out of every fast corner (docs/results/
    state-expressway-hatchback-clean). Below 1, their mean action can open the throttle fully (not in the papers)."""
    car_penalty_c_c: float = 0.005
    """c_c of the overtaking reward (section IV-B: 0.005)."""
    overtake_gain_c_r: float = 1.0
    """c_r of the overtaking reward; the paper gives no value: 1 weighs closing in like progress."""
    detection_range_c_d_m: float = 50.0
    """c_d: opponents within this progress gap enter the overtaking term; the paper gives no value."""
    opponent_skill: tuple[float, float] = OPPONENT_SKILL_RANGE
    """Opponents' skills are drawn uniformly in this range (share of the limit profile)."""
    start_skill: float = DEFAULT_SKILL
    """An episode starts at this share of the limit speed at the start point (the AI's speed there)."""
    terminate_when_stuck: bool = False
    """End (terminate) an episode when the ego is stuck by :data:`vision_rl.sim.fleet.STUCK_RULE`."""
    restart_before_stuck_share: float = 0.0
    """With ``terminate_when_stuck``: this share of episode starts is placed up to ``restart_before_stuck_m`` before
    a point where an ego of this environment got stuck (one of the last :data:`STUCK_POINTS_KEPT`), the rest at
    uniformly random points, so a policy meets the approaches it fails more often than once a lap (not in the
    papers; 0: every start random, as theirs). The places live in the environment's memory: each sampler process
    keeps its own, and a resumed training run gathers them anew."""
    restart_before_stuck_m: float = 300.0
    """How far before a stuck point such a start may be, m (uniformly within it). The losses of ``make quick``'s
    vision policies begin at full throttle at about 150 km/h, 2-4 s before the wall (docs/results/
    vision-expressway-hatchback), so 300 m covers the approach and its braking point."""
    terminate_on_wall: bool = False
    """End (terminate) an episode at the first control step in which the ego touches a wall, as the DDPG paper ends
    one on a crash (not in the GT Sport papers: their wall penalty alone). The step keeps its reward."""
    normalize: bool = True
    """Normalise vector observations (z-score; lidar min-max) with cached statistics."""
    image_hw_px: tuple[int, int] = (280, 470)
    """Height, width of the ``vision`` frames, px."""
    critic_state: bool = False
    """Vision with an encoder: the observation vector carries the 38-D ``state`` observation after the actor's
    columns, for a critic that reads both (an asymmetric actor-critic, as the DDPG paper's critic reads state its
    actor cannot see; not in the GT Sport papers). The actor reads its own columns alone, and the lap-time
    protocol's drivers never compute the state part (:mod:`vision_rl.training.critic_state`)."""
    extra: dict = field(default_factory=dict, compare=False, hash=False)
    """Free-form notes carried with the config (not used by the environment)."""

    def __post_init__(self) -> None:
        obs_lib.ObservationKind.of(self.observation)
        if self.scenario not in SCENARIOS:
            raise ValueError(f"scenario must be one of {tuple(SCENARIOS)}, got {self.scenario!r}")
        if self.steer_action not in STEER_ACTIONS:
            raise ValueError(f"steer_action must be one of {STEER_ACTIONS}, got {self.steer_action!r}")
        if self.wall_penalty_speed not in WALL_PENALTY_SPEEDS:
            raise ValueError(
                f"wall_penalty_speed must be one of {WALL_PENALTY_SPEEDS}, got {self.wall_penalty_speed!r}"
            )
        if self.steer_change_penalty_scale not in STEER_CHANGE_PENALTY_SCALES:
            raise ValueError(
                f"steer_change_penalty_scale must be one of {STEER_CHANGE_PENALTY_SCALES}, "
                f"got {self.steer_change_penalty_scale!r}"
            )
        if self.n_groups < 1:
            raise ValueError(f"n_groups must be >= 1, got {self.n_groups}")
        if min(self.wall_penalty_c_w, self.steer_change_penalty_c_s, self.off_track_penalty_c_o) < 0:
            raise ValueError("the reward's penalty weights (c_w, c_s, c_o) must be >= 0")
        if self.steer_change_share_of_range < 0:
            raise ValueError(f"steer_change_share_of_range must be >= 0, got {self.steer_change_share_of_range}")
        if self.steer_change_share_of_range > 0 and self.steer_action != "rate_scaled":
            raise ValueError("steer_change_share_of_range limits rate_scaled steering: use steer_action='rate_scaled'")
        if not 0 < self.pedal_full_at <= 1:
            raise ValueError(f"pedal_full_at must be within (0, 1], got {self.pedal_full_at}")
        if not 0 <= self.restart_before_stuck_share <= 1:
            raise ValueError(f"restart_before_stuck_share must be within [0, 1], got {self.restart_before_stuck_share}")
        if self.restart_before_stuck_share > 0 and not self.terminate_when_stuck:
            raise ValueError("restart_before_stuck_share starts episodes before stuck ends: use terminate_when_stuck")
        if self.restart_before_stuck_m < 0:
            raise ValueError(f"restart_before_stuck_m must be >= 0, got {self.restart_before_stuck_m}")
        if self.wall_hit_throttle_cut_s < 0:
            raise ValueError(f"wall_hit_throttle_cut_s must be >= 0, got {self.wall_hit_throttle_cut_s}")
        if not (isinstance(self.episode_s, int | float) and 0 < self.episode_s <= DURATION_MAX_S):
            # NaN or 1e308 s failed later in round(episode_s / control_dt_s) as a bare ValueError or OverflowError
            raise ValueError(
                f"episode_s must be a number of seconds in (0, {DURATION_MAX_S:g}], got {self.episode_s!r}"
            )
        if self.episode_s < self.control_dt_s:
            raise ValueError("episode_s must cover at least one control step")
        if ai_ticks(self.control_dt_s) is None:
            raise ValueError(f"control_dt_s must be a whole multiple of the AI's {AI_CONTROL_DT_S} s")

    @property
    def kind(self) -> obs_lib.ObservationKind:
        """What the egos observe, as a type (``observation`` is its name)."""
        return obs_lib.ObservationKind(self.observation)

    @property
    def opponents(self) -> int:
        return SCENARIOS[self.scenario][0]

    @property
    def throttle_cut_steps(self) -> int:
        """Control steps of the throttle cut after a wall hit (``wall_hit_throttle_cut_s``, rounded)."""
        return round(self.wall_hit_throttle_cut_s / self.control_dt_s)

    @property
    def max_episode_steps(self) -> int:
        return round(self.episode_s / self.control_dt_s)


class RacingCore:
    """M groups racing in one world; rewards and episode bookkeeping for the M egos, observations through one
    :class:`~vision_rl.envs.observer.Observer`.

    Seeding: group g draws its episodes' start points (and opponents' skills) from its own generator, child g of
    ``numpy.random.SeedSequence(seed)``, so the same seed gives group g the same episodes whatever the number of
    groups and whichever builder made the environment.

    The world steps at the built-in AI's 0.02 s; an ego's command is held over the control step (the same physics
    as one 0.1 s step), opponents are driven by the AI at each world step.

    Args:
        config: the environment.
        seed: see above (None: fresh entropy).
        observer: the observation maker (default: ``config.observation`` with the cached normalisation when
            ``config.normalize``, no encoder).
    """

    def __init__(self, config: RacingConfig, seed: int | None = None, observer: Observer | None = None) -> None:
        self.config = cfg = config
        self.track = load_track(cfg.track)
        self.car = get_preset(cfg.car)
        self.group_size = cfg.opponents + 1
        n_cars = cfg.n_groups * self.group_size
        self.ego_ids = np.arange(cfg.n_groups) * self.group_size
        self.groups = np.repeat(np.arange(cfg.n_groups), self.group_size)
        self.world_steps = ai_ticks(cfg.control_dt_s)
        self.world = World(self.track, self.car, n_cars, self.groups, WorldConfig(control_dt_s=AI_CONTROL_DT_S))
        self.line, self.profile = line_and_profile(self.track, self.car)
        self.fleet = AIFleet(self.world, self.line, self.profile, skill=cfg.start_skill)
        self.unwrapped_at_reset = np.zeros(n_cars)
        self.labeller: AIDriver | None = None
        """The built-in AI that :meth:`ai_actions` asks (None until :meth:`label_with_ai`)."""
        self.seed(seed)
        m = cfg.n_groups
        self.steps = np.zeros(m, dtype=np.int64)
        self.progress_m = np.zeros(m)
        self.steer_command_rad = np.zeros(m)
        self.touching_wall = np.zeros(m, dtype=bool)
        self.throttle_cut_left = np.zeros(m, dtype=np.int64)
        """Control steps left of each ego's throttle cut after a wall hit (``wall_hit_throttle_cut_s``)."""
        self.start_gap_m = np.zeros((m, cfg.opponents))
        self.gap_m = np.zeros((m, cfg.opponents))
        self.stuck = StuckDetector(self.world.state.unwrapped_s_m[self.ego_ids], cfg.control_dt_s)
        self.stuck_points_s_m = np.empty(0)
        """Where egos got stuck, track arc length, m: the last :data:`STUCK_POINTS_KEPT`, oldest first."""
        if cfg.critic_state and not cfg.kind.sees_frames:  # checked here: a trainer's config sets the kind late
            raise ValueError(f"critic_state appends the state observation to the vision vector, not to {cfg.kind}")
        if observer is None:
            observer = Observer(cfg.observation, self.track, self.car, self.groups, image_hw_px=cfg.image_hw_px)
            if cfg.normalize and not cfg.kind.sees_frames:
                observer.normalizer = obs_lib.load_or_compute_normalizer(
                    self.track, self.car.name, cfg.observation, lambda: _statistics_sample(cfg)
                )
        self.observer = observer

    @property
    def observer(self) -> Observer:
        return self._observer

    @observer.setter
    def observer(self, observer: Observer) -> None:
        # Whatever observer a trainer puts in (one with its encoder) renders with this environment's frame delay.
        observer.delay_frames(self.config.frame_delay_s, self.config.control_dt_s)
        self._observer = observer

    @property
    def skill(self) -> np.ndarray:
        """(n_cars,) skill of every car's AI (the egos' is used only when the AI drives them)."""
        return self.fleet.skill

    def seed(self, seed: int | None) -> None:
        """New generators for every group (see the class docstring)."""
        children = np.random.SeedSequence(seed).spawn(self.config.n_groups)
        self.group_rngs = [np.random.default_rng(child) for child in children]

    # ------------------------------------------------------------------ placement
    def reset_groups(self, gids: np.ndarray) -> None:
        """New episodes for the groups ``gids``: random start point (or one before a stuck point, see
        ``RacingConfig.restart_before_stuck_share``), AI speed, opponents ahead on the racing line."""
        cfg, k = self.config, self.group_size
        gids = np.asarray(gids, dtype=np.int64)
        if len(gids) == 0:
            return
        skill = np.full((len(gids), k), cfg.start_skill)
        s0 = np.empty(len(gids))
        stuck_points = self.stuck_points_s_m
        for row, g in enumerate(gids):  # one draw per group from its own generator (a reset, not a step)
            rng = self.group_rngs[g]
            s0[row] = rng.uniform(0.0, self.track.length_m)
            if cfg.restart_before_stuck_share > 0:
                # Drawn whatever the choice, so a group's later draws do not depend on the stuck points so far.
                choose, pick, back = rng.uniform(size=3)
                if choose < cfg.restart_before_stuck_share and len(stuck_points):
                    point_s_m = stuck_points[int(pick * len(stuck_points))]
                    s0[row] = (point_s_m - back * cfg.restart_before_stuck_m) % self.track.length_m
            if k > 1:
                skill[row, 1:] = rng.uniform(cfg.opponent_skill[0], cfg.opponent_skill[1], k - 1)
        offsets = np.arange(k) * SCENARIOS[cfg.scenario][1]
        car_ids = (gids[:, None] * k + np.arange(k)[None, :]).ravel()
        self.skill[car_ids] = skill.ravel()
        self.fleet.place(car_ids, (s0[:, None] + offsets[None, :]).ravel())
        self.unwrapped_at_reset[car_ids] = self.world.state.unwrapped_s_m[car_ids]
        self.observer.restart(self.world.state, car_ids)
        self.steps[gids] = 0
        self.progress_m[gids] = 0.0
        # An episode starts from the wheel angle the car was placed with, so a first command that keeps it is free.
        self.steer_command_rad[gids] = self.world.state.vehicle.steer_rad[self.ego_ids[gids]]
        self.touching_wall[gids] = False
        self.throttle_cut_left[gids] = 0
        self.stuck.reset(gids, self.world.state.unwrapped_s_m[self.ego_ids])
        if k > 1:
            self.gap_m[gids] = self._gaps()[gids]
            self.start_gap_m[gids] = self.gap_m[gids]

    def _gaps(self) -> np.ndarray:
        """(M, K) wrapped progress gaps from each ego to its opponents, m (positive: the opponent is ahead)."""
        s = self.world.state.s_m.reshape(self.config.n_groups, self.group_size)
        return wrapped_gap_m(s[:, 1:], s[:, :1], self.track.length_m)

    # ------------------------------------------------------------------ observations
    def raw_observation(self) -> np.ndarray:
        """The egos' observation vectors before normalisation."""
        return self.observer.raw(self.world.state, self.ego_ids)

    def observation(self, gids: np.ndarray | None = None) -> np.ndarray | dict[str, np.ndarray]:
        """The observations of the egos (or of groups ``gids``) as the environments return them."""
        ids = self.ego_ids if gids is None else self.ego_ids[gids]
        return self.observer(self.world.state, ids)

    def vision_observer(self, encoder, normalizer: obs_lib.ObsNormalizer | None = None) -> Observer:
        """An observer of this environment's vision vector with a frame ``encoder`` (frame size and the critic's state
        columns as its config says), for a trainer or a sampler to put in as :attr:`observer`."""
        cfg = self.config
        return Observer(
            obs_lib.ObservationKind.VISION,
            self.track,
            self.car,
            self.groups,
            normalizer,
            encoder,
            cfg.image_hw_px,
            critic_state=cfg.critic_state,
        )

    def sample_raw_observations(self, observer: Observer, steps: int = 300) -> np.ndarray:
        """Raw observations by ``observer`` of the egos driven by the disrupted built-in AI from random starts over
        ``steps`` control steps (at least 6,000 samples): what normalisation statistics are computed from. Uses
        its own generators, so the environment's seeds neither change them nor are changed by them."""
        saved = self.group_rngs
        observer.delay_frames(self.config.frame_delay_s, self.config.control_dt_s)
        self.seed(STATS_SEED)
        self.fleet.disruptor = Disruptor(self.world.n_cars, seed=STATS_SEED)
        samples = []
        try:
            self.reset_groups(np.arange(self.config.n_groups))
            observer.restart(self.world.state)
            for _ in range(max(steps, 20 * steps // self.config.n_groups)):
                self.fleet.advance(self.world_steps)
                observer.remember(self.world.state)
                samples.append(observer.raw(self.world.state, self.ego_ids))
        finally:
            self.fleet.disruptor = None
            self.group_rngs = saved
        return np.concatenate(samples)

    # ------------------------------------------------------------------ stepping
    def advance(self, ego_steer_rad: np.ndarray, ego_omega: np.ndarray) -> StepEvents:
        """One control step: the egos' commands held, the built-in AI driving every other car at its rate."""
        return self.fleet.advance(self.world_steps, self.ego_ids, ego_steer_rad, ego_omega)

    def step(self, actions: np.ndarray, autoreset: bool) -> tuple:
        """Apply the egos' actions (M, 2) ``[steer rad, omega]``, the AI drives the opponents.

        Returns (obs, reward (M,), terminated (M,), truncated (M,), infos: list of M dicts). With ``autoreset``,
        groups whose episode ended are reset in the same step: their returned observation is the new episode's
        first one and their info holds ``final_observation`` and ``final_info`` (Stable-Baselines3 semantics).
        """
        cfg = self.config
        actions = np.asarray(actions, dtype=np.float64).reshape(cfg.n_groups, 2)
        st = self.world.state
        s_prev = st.s_m[self.ego_ids].copy()
        ego_speed = np.hypot(st.vehicle.vx_mps[self.ego_ids], st.vehicle.vy_mps[self.ego_ids])
        steer_rad = steering_command(
            actions[:, 0],
            self.steer_command_rad,
            cfg.steer_action,
            self.max_change_rad,
            ego_speed,
            self.car.wheelbase_m,
            cfg.steer_change_share_of_range,
        )
        omega = pedal_command(actions[:, 1], cfg.pedal_full_at)
        omega = np.where(self.throttle_cut_left > 0, np.minimum(omega, 0.0), omega)
        events = self.advance(steer_rad, omega)
        return self._after_step(s_prev, ego_speed, steer_rad, events, autoreset)

    @property
    def max_change_rad(self) -> float:
        """The most the steering command may move in one control step under ``rate`` actions (the car's rate
        limit), rad."""
        return self.car.max_steer_rate_radps * self.config.control_dt_s

    def guided_step(self, autoreset: bool) -> tuple:
        """One control step in which the built-in AI drives the egos too, at its own rate and the egos' start skill
        (clean laps): demonstrations for an off-policy learner (not in the papers).

        Returns :meth:`step`'s five values and the actions (M, 2) of this environment's action space that ask for
        what the AI did (:func:`action_for_command`): the steering command it ended the step with and its
        throttle/brake averaged over the step. The AI changes its commands within the step, so replaying those
        actions drives close to, not exactly along, its path."""
        ego = self.ego_ids
        st = self.world.state
        s_prev = st.s_m[ego].copy()
        ego_speed = np.hypot(st.vehicle.vx_mps[ego], st.vehicle.vy_mps[ego])
        events = self.fleet.advance(self.world_steps)
        steer_rad = np.clip(self.fleet.last_steer_rad[ego], -ACTION_STEER_LIMIT_RAD, ACTION_STEER_LIMIT_RAD)
        actions = self._actions_asking_for(steer_rad, self.fleet.mean_omega[ego], ego_speed)
        return (*self._after_step(s_prev, ego_speed, steer_rad, events, autoreset), actions)

    def label_with_ai(self, skill: float) -> None:
        """Let :meth:`ai_actions` ask the built-in AI at ``skill``: a driver of its own, so the skills of the
        opponents and of guided egos stay as they are."""
        self.labeller = AIDriver(
            self.car, self.line, self.profile, self.world.n_cars, skill=skill, groups=self.world.model.groups
        )

    def ai_actions(self) -> np.ndarray:
        """(M, 2) actions of this environment's action space that ask, for the egos as they are now, for the
        commands the labeller's AI would give (it then corrects them within the step; held, they drive close to
        its path): labels of the states a policy visits (not in the papers)."""
        if self.labeller is None:
            raise RuntimeError("ai_actions needs label_with_ai first")
        steer, omega = self.labeller.act(self.world.state)
        ego, st = self.ego_ids, self.world.state
        command = np.clip(steer[ego], -ACTION_STEER_LIMIT_RAD, ACTION_STEER_LIMIT_RAD)
        return self._actions_asking_for(command, omega[ego], np.hypot(st.vehicle.vx_mps[ego], st.vehicle.vy_mps[ego]))

    def _actions_asking_for(self, command_rad: np.ndarray, omega: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
        """(M, 2) actions that ask :meth:`step` for the egos' steering commands ``command_rad`` and throttle/brake
        ``omega`` (see :func:`action_for_command`)."""
        cfg = self.config
        steer = action_for_command(
            command_rad,
            self.steer_command_rad,
            cfg.steer_action,
            self.max_change_rad,
            speed_mps,
            self.car.wheelbase_m,
            cfg.steer_change_share_of_range,
        )
        return np.column_stack([steer, action_for_pedal(omega, cfg.pedal_full_at)])

    def _after_step(self, s_prev: np.ndarray, ego_speed: np.ndarray, steer_rad: np.ndarray, events, autoreset: bool):
        """Rewards, ends and observations of a control step the world has just advanced (see :meth:`step`)."""
        cfg = self.config
        self.observer.remember(self.world.state)
        st = self.world.state
        ego = self.ego_ids
        progress = self.track.progress_delta(s_prev, st.s_m[ego])
        speed = np.hypot(st.vehicle.vx_mps[ego], st.vehicle.vy_mps[ego])
        wall_speed = wall_penalty_speed_mps(ego_speed, speed, cfg.wall_penalty_speed)
        reward = racing_reward(progress, st.wall_contact[ego], wall_speed, cfg.wall_penalty_c_w)
        if cfg.off_track_penalty_c_o > 0:
            # The body's outer side, not its centre: on our tracks the band between the edge line and the wall is
            # at most 1 m wide, so a centre beyond the line leaves less than 0.2 m to the wall.
            lateral = st.lateral_m[ego]
            beyond = self.track.beyond_edge_line(st.s_m[ego], lateral + np.copysign(0.5 * self.car.width_m, lateral))
            reward = reward - off_track_penalty(beyond, speed, cfg.off_track_penalty_c_o)
        if cfg.steer_change_penalty_c_s > 0:
            scale_rad = ACTION_STEER_LIMIT_RAD
            if cfg.steer_change_penalty_scale == "usable":
                scale_rad = usable_steer_rad(ego_speed, self.car.wheelbase_m)
            reward = reward - steering_change_penalty(
                self.steer_command_rad, steer_rad, scale_rad, cfg.steer_change_penalty_c_s
            )
        self.steer_command_rad = steer_rad
        if self.group_size > 1:
            gap_now = self._gaps()
            reward = overtaking_reward(
                reward,
                st.car_contact[ego],
                speed,
                self.gap_m,
                gap_now,
                cfg.car_penalty_c_c,
                cfg.overtake_gain_c_r,
                cfg.detection_range_c_d_m,
            )
            self.gap_m = gap_now
        touching = st.wall_contact[ego]
        cut = np.maximum(self.throttle_cut_left - 1, 0)
        self.throttle_cut_left = np.where(touching & ~self.touching_wall, cfg.throttle_cut_steps, cut)
        self.touching_wall = touching.copy()
        self.steps += 1
        self.progress_m += progress
        terminated = np.zeros(cfg.n_groups, dtype=bool)
        stuck = self.stuck.update(st.unwrapped_s_m[ego])
        if cfg.terminate_when_stuck:
            terminated[stuck] = True
            if cfg.restart_before_stuck_share > 0 and len(stuck):
                kept = np.concatenate([self.stuck_points_s_m, st.s_m[ego[stuck]]])
                self.stuck_points_s_m = kept[-STUCK_POINTS_KEPT:]
        if cfg.terminate_on_wall:
            terminated[st.wall_contact[ego]] = True
        truncated = (self.steps >= cfg.max_episode_steps) & ~terminated
        infos = [self._info(g, events) for g in range(cfg.n_groups)]
        done = terminated | truncated
        if autoreset and done.any():
            gids = np.flatnonzero(done)
            final = self.observation(gids)
            for row, g in enumerate(gids):
                infos[g] = {"final_observation": _take(final, row), "final_info": infos[g]}
            self.reset_groups(gids)
        obs = self.observation()
        return obs, reward.astype(np.float32), terminated, truncated, infos

    def _info(self, g: int, events) -> dict:
        st, i = self.world.state, self.ego_ids[g]
        info = {
            "lap_times_s": list(self.world.lap_times_s[i]),
            "lap_completed": bool(events.lap_completed[i]),
            "progress_m": float(self.progress_m[g]),
            "wall_contact_s": float(st.wall_contact_time_s[i]),
            "speed_mps": float(np.hypot(st.vehicle.vx_mps[i], st.vehicle.vy_mps[i])),
            "episode_time_s": float(st.time_s[i]),
        }
        if self.group_size > 1:
            # The overtaking paper's four metrics (section IV-C) and the opponents passed so far.
            info.update(
                travel_time_s=float(st.time_s[i]),
                travel_distance_m=float(self.progress_m[g]),
                car_contact_s=float(st.car_contact_time_s[i]),
                overtaken=int(np.sum((self.start_gap_m[g] > 0.0) & (self._unwrapped_gaps(g) < 0.0))),
            )
        return info

    def _unwrapped_gaps(self, g: int) -> np.ndarray:
        """Gaps to group g's opponents counted with whole laps (so a lapped opponent stays passed), m."""
        ids = g * self.group_size + np.arange(self.group_size)
        travelled = self.world.state.unwrapped_s_m[ids] - self.unwrapped_at_reset[ids]
        return self.start_gap_m[g] + travelled[1:] - travelled[0]


def _take(obs, g: int):
    if isinstance(obs, dict):
        return {k: v[g] for k, v in obs.items()}
    return obs[g]


def _statistics_sample(config: RacingConfig) -> np.ndarray:
    """Raw observations for the cached normalisation of ``config``'s track, car and observation kind, always from
    :data:`STATS_GROUPS` groups: the statistics (and so the normalised observations) must not depend on which
    environment happened to compute them first (so they are sampled at the default control step too)."""
    dt = RacingConfig.control_dt_s
    pinned = dataclasses.replace(
        config,
        n_groups=STATS_GROUPS,
        normalize=False,
        control_dt_s=dt,
        episode_s=max(config.episode_s, dt),
        restart_before_stuck_share=0.0,
    )
    core = RacingCore(pinned)
    try:
        return core.sample_raw_observations(core.observer)
    finally:
        core.observer.close()
