"""``vision_rl/PixelRacing-v0``/``-v1``: the asymmetric actor-critic environment of the Project CARS 2 DDPG paper.

The actor sees the driver's-view pixels, the critic motion and the racing line; everything is batched over cars
(:class:`PixelRacingCore`), and :class:`PixelObserver` is the one place a world state becomes this environment's
observation. The observation's parts and the functions the tests pin down: docs/notes/envs.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from vision_rl.envs.observer import Observer
from vision_rl.envs.scaling import bounded_box, to_physical, unit_box
from vision_rl.sim.ai_driver import DEFAULT_SKILL
from vision_rl.sim.driving import line_and_profile
from vision_rl.sim.fleet import STUCK_RULE, StuckDetector
from vision_rl.sim.racing_line import RacingLine, racing_line_from_offsets
from vision_rl.sim.sensors import wrap_angle
from vision_rl.sim.track import Track, TrackError
from vision_rl.sim.track_library import load_track, reference_racing_line
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD, VehicleParams, get_preset
from vision_rl.sim.world import World, WorldConfig, WorldState

#: The actor's frame, (height, width) px: the paper's (89, 120, 3).
ACTOR_HW_PX = (89, 120)
#: Share of the frame's rows, from the top, that is black.
MASK_TOP_SHARE = 1.0 / 3.0
MOTION_NAMES = (
    "x_m",
    "y_m",
    "z_m",
    "roll_rad",
    "pitch_rad",
    "yaw_rad",
    "vx_mps",
    "vy_mps",
    "vz_mps",
    "roll_rate_radps",
    "pitch_rate_radps",
    "yaw_rate_radps",
    "ax_mps2",
    "ay_mps2",
    "az_mps2",
)
GOAL_NAMES = ("goal_x_m", "goal_y_m", "goal_z_m")
#: The actor's four outputs, in order (the paper's keys up, left, right, down).
KEY_NAMES = ("accelerate", "left", "right", "brake")
#: The paper's mCrashState values. Our planar model never rolls, so ROLLING is never set.
CRASH_NONE, CRASH_OFF_TRACK, CRASH_LARGE_PROP, CRASH_SPINNING, CRASH_ROLLING = 0, 1, 2, 3, 4
GOAL_FRAMES = ("world", "body")
RACING_LINES = ("car", "reference")
STARTS = ("random", "line")


class PixelRacingError(ValueError):
    """A setting or input this environment cannot use; the message names it and says what to do."""


@dataclass(frozen=True)
class PixelRacingConfig:
    """Everything that defines a PixelRacing environment; stored with DDPG agents so evaluation rebuilds it."""

    track: str = "Catalunya"
    """Track: a built-in or racetrack-database name, ``random:SEED`` or a CSV path (the paper: Barcelona-Catalunya)."""
    car: str = "gt3"
    """Car preset (the paper: a Porsche 911 GT3 R)."""
    n_cars: int = 1
    """Cars stepped together in one world, each alone on track (the vector form's sub-environments)."""
    control_dt_s: float = 0.1
    """Control step, s."""
    episode_s: float = 300.0
    """Truncation after this long, s (three laps of Catalunya in a GT3, as the paper monitored)."""
    image_hw_px: tuple[int, int] = ACTOR_HW_PX
    """The actor's frame, (height, width) px."""
    render_scale: int = 1
    """Frames are rendered at this multiple of ``image_hw_px`` and box-averaged down (2: 2x2 antialiasing)."""
    frames: bool = True
    """Render the ``image`` observation; False leaves it out (the state-only actor ablation needs no pixels)."""
    goal_frame: str = "world"
    """``world``: the goal is the racing-line point in world coordinates (the paper); ``body``: its offset from the car
    in the body frame (x forward, y left)."""
    racing_line: str = "car"
    """``car``: the car's minimum-curvature line (what the built-in AI and the limit lap follow); ``reference``: the
    racetrack-database's own race line (its circuits only)."""
    line_distance_alpha: float = 1.0
    """alpha of ``r = V - alpha |racing-line distance| - beta crashState``, (m/s) per m."""
    crash_penalty_beta: float = 0.0
    """beta of the paper's alternative reward, (m/s) per crashState unit (0: the simple reward)."""
    max_line_distance_m: float = 5.0
    """The episode ends (terminates) when the car is farther than this from its racing-line point, m."""
    terminate_on_crash: bool = True
    """The episode ends on a non-zero crashState (the paper's next-step rule)."""
    terminate_when_stuck: bool = True
    """The episode also ends when the car is stuck by the project's one rule (less than 5 m in 5 s)."""
    truncate_when_stuck: bool = False
    """A stuck car's episode ends as a truncation, not a termination, whatever ``terminate_when_stuck`` says (not in
    the paper): a learner bootstraps the stuck state's value, so stopping against a wall is worth what staying there
    costs, not a terminal 0."""
    spin_slip_deg: float = 30.0
    """Sideslip angle above which a moving car is spinning (crashState 3), deg."""
    start: str = "random"
    """``random``: a uniformly random point of the track; ``line``: the start/finish line. On the racing line,
    heading along the track, at ``start_skill`` x the limit speed there."""
    start_skill: float = DEFAULT_SKILL
    """Share of the limit speed a car starts at (the built-in AI's speed; 0: from standstill, as a race in the game
    restarts)."""

    def __post_init__(self) -> None:
        checks = [
            (self.n_cars >= 1, "n_cars", "at least 1"),
            (self.control_dt_s > 0, "control_dt_s", "positive"),
            (self.episode_s >= self.control_dt_s, "episode_s", "at least one control step"),
            (len(self.image_hw_px) == 2 and min(self.image_hw_px) >= 8, "image_hw_px", "two sizes of 8 px or more"),
            (1 <= self.render_scale <= 8, "render_scale", "within 1..8"),
            (self.goal_frame in GOAL_FRAMES, "goal_frame", f"one of {GOAL_FRAMES}"),
            (self.racing_line in RACING_LINES, "racing_line", f"one of {RACING_LINES}"),
            (self.start in STARTS, "start", f"one of {STARTS}"),
            (self.line_distance_alpha >= 0, "line_distance_alpha", ">= 0"),
            (self.crash_penalty_beta >= 0, "crash_penalty_beta", ">= 0"),
            (self.max_line_distance_m > 0, "max_line_distance_m", "positive"),
            (0 < self.spin_slip_deg < 180, "spin_slip_deg", "within (0, 180)"),
            (0 <= self.start_skill <= 1, "start_skill", "within [0, 1]"),
        ]
        for ok, name, want in checks:
            if not ok:
                raise PixelRacingError(f"PixelRacing {name} = {getattr(self, name)!r} must be {want}")
        object.__setattr__(self, "image_hw_px", (int(self.image_hw_px[0]), int(self.image_hw_px[1])))

    @property
    def max_episode_steps(self) -> int:
        return round(self.episode_s / self.control_dt_s)

    @property
    def mask_rows(self) -> int:
        """Rows from the top that are black."""
        return math.ceil(self.image_hw_px[0] * MASK_TOP_SHARE - 1e-9)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["image_hw_px"] = list(self.image_hw_px)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PixelRacingConfig:
        known = {f for f in cls.__dataclass_fields__}
        unknown = set(data) - known
        if unknown:
            raise PixelRacingError(f"PixelRacing config has unknown fields {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


# ------------------------------------------------------------------------------------------------ pure functions


#: The range of the actor's four outputs ``[accelerate, left, right, brake]``, float64.
KEYS_LOW = np.array([0.0, -1.0, -1.0, 0.0])
KEYS_HIGH = np.ones(4)


def action_space(normalized: bool = False) -> spaces.Box:
    """The actor's four outputs ``[accelerate, left, right, brake]``: accelerate and brake in [0, 1] (relu outputs,
    clipped at 1), left and right in [-1, 1] (tanh outputs); ``Box(-1, 1, (4,))`` with ``normalized`` (mapped onto
    those ranges by :func:`physical_keys`)."""
    if normalized:
        return unit_box(4)
    return spaces.Box(KEYS_LOW.astype(np.float32), KEYS_HIGH.astype(np.float32), dtype=np.float32)


def physical_keys(actions: np.ndarray, normalized: bool) -> np.ndarray:
    """Actions (..., 4) as the actor's outputs, float64: normalized ones mapped linearly onto their ranges (accelerate
    and brake ``(a + 1) / 2``, left and right as they are; clipped to [-1, 1] first), the others as they are."""
    actions = np.asarray(actions, dtype=np.float64)
    return to_physical(actions, KEYS_LOW, KEYS_HIGH) if normalized else actions


def keys_to_action(keys: np.ndarray) -> np.ndarray:
    """The actor's outputs (n, 4) as our action (n, 2) ``[steering rad, omega]``.

    The paper holds each key for 0.1-1.5 s; at a fixed 0.1 s step a key becomes the share of the step it is held,
    a duty cycle in [0, 1]: accelerate and brake are their relu outputs clipped to [0, 1], left and right their tanh
    outputs mapped from [-1, 1] to [0, 1] (``(t + 1) / 2``, so a fresh actor's near-zero outputs hold both keys
    half the step and steer straight, and no part of the range is dead). Then

    ``steer = (left - right) * pi/6`` (full left alone: +pi/6, full right alone: -pi/6, both or neither: 0) and
    ``omega = accelerate - brake`` (full throttle 1, full brake -1, both: they cancel).
    """
    k = np.asarray(keys, dtype=np.float64).reshape(-1, 4)
    k = np.nan_to_num(k, nan=0.0)
    accelerate, brake = np.clip(k[:, 0], 0.0, 1.0), np.clip(k[:, 3], 0.0, 1.0)
    left, right = 0.5 * (np.clip(k[:, 1], -1.0, 1.0) + 1.0), 0.5 * (np.clip(k[:, 2], -1.0, 1.0) + 1.0)
    return np.stack([(left - right) * ACTION_STEER_LIMIT_RAD, accelerate - brake], axis=1)


def process_frames(frames: np.ndarray, render_scale: int, mask_rows: int) -> np.ndarray:
    """Frames (n, s*H, s*W, 3) uint8 rendered at ``render_scale`` s, box-averaged to (n, H, W, 3), top ``mask_rows``
    rows black."""
    n, hs, ws, c = frames.shape
    if render_scale > 1:
        s = render_scale
        blocks = frames.reshape(n, hs // s, s, ws // s, s, c).astype(np.uint16).sum(axis=(2, 4))
        frames = ((blocks + (s * s) // 2) // (s * s)).astype(np.uint8)
    else:
        frames = np.array(frames, dtype=np.uint8, copy=True)
    frames[:, :mask_rows] = 0
    return frames


def motion_state(state: WorldState, ids: np.ndarray) -> np.ndarray:
    """The 15-D motion state (len(ids), 15) in :data:`MOTION_NAMES` order. The planar model has no height, heave or
    vertical acceleration: those are 0."""
    v = state.vehicle
    out = np.zeros((len(ids), 15), dtype=np.float64)
    out[:, 0], out[:, 1] = v.x_m[ids], v.y_m[ids]
    out[:, 3], out[:, 4], out[:, 5] = v.roll_rad[ids], v.pitch_rad[ids], v.yaw_rad[ids]
    out[:, 6], out[:, 7] = v.vx_mps[ids], v.vy_mps[ids]
    out[:, 9], out[:, 10], out[:, 11] = v.roll_rate_radps[ids], v.pitch_rate_radps[ids], v.yaw_rate_radps[ids]
    out[:, 12], out[:, 13] = v.ax_mps2[ids], v.ay_mps2[ids]
    return out


def racing_line_goal(line: RacingLine, s_m: np.ndarray, x_m: np.ndarray, y_m: np.ndarray) -> tuple:
    """The racing-line point matched to cars at centre-line arc length ``s_m`` and position (x, y): the line's point
    on the car's cross-section of the track (where the line crosses the normal through the car's projection on the
    centre line; on a straight the closest point of the line). Returns (goal (n, 2) world x, y in m, distance from
    the car to it (n,) in m)."""
    s = np.asarray(s_m, dtype=np.float64)
    goal = line.position_at(line.line_s_at(s)).reshape(len(s), 2)
    return goal, np.hypot(goal[:, 0] - x_m, goal[:, 1] - y_m)


def crash_state(
    track: Track, state: WorldState, ids: np.ndarray, spin_slip_rad: float, min_speed_mps: float = 3.0
) -> np.ndarray:
    """The paper's crashState (len(ids),) int, the most severe that applies:

    - 3 spinning: moving faster than ``min_speed_mps`` with a sideslip ``|atan2(vy, vx)|`` above ``spin_slip_rad``,
      or heading more than 90 deg away from the track's direction (turned round);
    - 2 large prop: touched a wall during the last step (our tracks' only props are the barriers);
    - 1 off-track: the car's centre beyond the painted edge line, on the kerb or shoulder band;
    - 0 none. (4, rolling, never happens: the model is planar.)
    """
    v = state.vehicle
    vx, vy = v.vx_mps[ids], v.vy_mps[ids]
    s = state.s_m[ids]
    sliding = (np.hypot(vx, vy) > min_speed_mps) & (np.abs(np.arctan2(vy, vx)) > spin_slip_rad)
    turned = np.abs(wrap_angle(v.yaw_rad[ids] - track.heading_at(s))) > 0.5 * np.pi
    code = np.where(track.beyond_edge_line(s, state.lateral_m[ids]), CRASH_OFF_TRACK, CRASH_NONE)
    code = np.where(state.wall_contact[ids], CRASH_LARGE_PROP, code)
    return np.where(sliding | turned, CRASH_SPINNING, code).astype(np.int64)


def pixel_reward(
    forward_speed_mps: np.ndarray, line_distance_m: np.ndarray, crash: np.ndarray, alpha: float, beta: float
) -> np.ndarray:
    """``r = V - alpha |racing-line distance| - beta crashState`` (V: body-frame forward speed, m/s)."""
    return forward_speed_mps - alpha * np.abs(line_distance_m) - beta * np.asarray(crash, dtype=np.float64)


def goal_line(track: Track, car: VehicleParams, which: str, track_spec: str = "") -> RacingLine:
    """The racing line the goal follows: the car's minimum-curvature line, or the racetrack-database's race line of
    ``track_spec`` mapped onto the track (its points projected to offsets from the centre line)."""
    if which == "car":
        return line_and_profile(track, car)[0]
    try:
        ref = reference_racing_line(track_spec or track.name)
    except TrackError:
        raise PixelRacingError(
            f"track {track_spec or track.name!r} has no reference racing line (only the racetrack-database circuits "
            "ship one): use racing_line='car', the car's own minimum-curvature line"
        ) from None
    proj = track.project(ref)
    order = np.argsort(proj.s_m)
    s, lateral = proj.s_m[order], proj.lateral_m[order]
    lateral_at = np.interp(track.s_m, np.concatenate([s - track.length_m, s, s + track.length_m]), np.tile(lateral, 3))
    return racing_line_from_offsets(track, lateral_at)


def critic_input_scale(track: Track, car: VehicleParams, goal_frame: str) -> tuple[np.ndarray, np.ndarray]:
    """(offset, scale) of the 18 critic inputs (15 motion, 3 goal) so that ``(x - offset) / scale`` is of order one:
    positions about the track's bounding-box centre over its half extent, speeds over the car's top speed (or
    100 m/s), angles over pi, rates over 1 rad/s, accelerations over 20 m/s^2, a body-frame goal over 10 m."""
    lo, hi = track.centre_xy_m.min(axis=0), track.centre_xy_m.max(axis=0)
    centre, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 1.0)
    vmax = car.max_speed_mps if math.isfinite(car.max_speed_mps) else 100.0
    offset = np.zeros(18)
    scale = np.ones(18)
    offset[0:2], scale[0:2] = centre, half
    scale[3:6] = [0.1, 0.1, np.pi]
    scale[6:9] = [vmax, 10.0, 1.0]
    scale[9:12] = [1.0, 1.0, 1.0]
    scale[12:15] = [20.0, 20.0, 1.0]
    if goal_frame == "world":
        offset[15:17], scale[15:17] = centre, half
    else:
        scale[15:17] = 10.0
    return offset.astype(np.float32), scale.astype(np.float32)


# ------------------------------------------------------------------------------------------------ observer


class PixelObserver:
    """Observations ``{image, motion, goal}`` of cars ``ids`` of a world (``image`` only with ``config.frames``).

    Owns the renderer (through an :class:`~vision_rl.envs.observer.Observer` of kind ``vision``, created on the first
    frame) and the racing line; used by the environment and by the lap-time protocol's DDPG driver alike.
    """

    def __init__(
        self, config: PixelRacingConfig, track: Track, car: VehicleParams, groups: np.ndarray, batch_cars: int = 0
    ) -> None:
        self.config = config
        self.track, self.car = track, car
        self.line = goal_line(track, car, config.racing_line, config.track)
        hw = config.image_hw_px
        self._frames = Observer(  # batch_cars: the renderer's views per pass (see Observer)
            "vision",
            track,
            car,
            groups,
            image_hw_px=(hw[0] * config.render_scale, hw[1] * config.render_scale),
            batch_cars=batch_cars,
        )
        self._spin_rad = math.radians(config.spin_slip_deg)

    @property
    def space(self) -> spaces.Dict:
        """One car's observation space."""
        d: dict[str, spaces.Space] = {}
        if self.config.frames:
            d["image"] = spaces.Box(0, 255, (*self.config.image_hw_px, 3), dtype=np.uint8)
        d["motion"] = spaces.Box(-np.inf, np.inf, (15,), dtype=np.float32)
        d["goal"] = spaces.Box(-np.inf, np.inf, (3,), dtype=np.float32)
        return spaces.Dict(d)

    def bounded_space(self) -> spaces.Dict:
        """:attr:`space` with the bounds known by definition (PixelRacing-v1): a world-frame goal lies on the racing
        line, within its bounding box in x and y; the rest stays (-inf, inf)."""
        d = dict(self.space.spaces)
        if self.config.goal_frame == "world":
            low, high = np.full(3, -np.inf), np.full(3, np.inf)
            low[:2], high[:2] = self.line.xy_m.min(axis=0), self.line.xy_m.max(axis=0)
            d["goal"] = bounded_box(low, high)
        return spaces.Dict(d)

    def frames(self, state: WorldState, ids: np.ndarray) -> np.ndarray:
        """The actor's frames (len(ids), H, W, 3) uint8: rendered, box-averaged, top third black."""
        raw = self._frames.frames(state, ids)
        return process_frames(raw, self.config.render_scale, self.config.mask_rows)

    def goal(self, state: WorldState, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(goal (len(ids), 3) in the configured frame, distance to the racing-line point (len(ids),) m)."""
        v = state.vehicle
        x, y = v.x_m[ids], v.y_m[ids]
        xy, dist = racing_line_goal(self.line, state.s_m[ids], x, y)
        goal = np.zeros((len(ids), 3))
        if self.config.goal_frame == "world":
            goal[:, :2] = xy
        else:
            dx, dy, yaw = xy[:, 0] - x, xy[:, 1] - y, v.yaw_rad[ids]
            c, s = np.cos(yaw), np.sin(yaw)
            goal[:, 0], goal[:, 1] = c * dx + s * dy, -s * dx + c * dy
        return goal, dist

    def crash_state(self, state: WorldState, ids: np.ndarray) -> np.ndarray:
        return crash_state(self.track, state, ids, self._spin_rad)

    def __call__(self, state: WorldState, ids: np.ndarray) -> dict[str, np.ndarray]:
        ids = np.asarray(ids)
        goal, _ = self.goal(state, ids)
        obs = {"motion": motion_state(state, ids).astype(np.float32), "goal": goal.astype(np.float32)}
        if self.config.frames:
            obs = {"image": self.frames(state, ids), **obs}
        return obs

    def close(self) -> None:
        self._frames.close()


# ------------------------------------------------------------------------------------------------ the batched core


def take(obs: dict[str, np.ndarray], rows: np.ndarray | int) -> dict[str, np.ndarray]:
    """Rows of a batched observation dict."""
    return {k: v[rows] for k, v in obs.items()}


class PixelRacingCore:
    """``config.n_cars`` cars, each alone, in one world: placement, the step (keys -> action -> physics), reward,
    crashState and termination for all cars at once.

    Seeding: one generator (``numpy.random.default_rng(seed)``) draws every reset's start points, so the same seed
    and number of cars give the same episodes.
    """

    def __init__(self, config: PixelRacingConfig, seed: int | None = None) -> None:
        self.config = cfg = config
        self.track = load_track(cfg.track)
        self.car = get_preset(cfg.car)
        n = cfg.n_cars
        self.ids = np.arange(n)
        self.world = World(self.track, self.car, n, np.arange(n), WorldConfig(control_dt_s=cfg.control_dt_s))
        self.observer = PixelObserver(cfg, self.track, self.car, np.arange(n))
        self.ai_line, self.profile = line_and_profile(self.track, self.car)
        self.rng = np.random.default_rng(seed)
        self.steps = np.zeros(n, dtype=np.int64)
        self.return_ = np.zeros(n)
        self.progress_m = np.zeros(n)
        self.stuck = StuckDetector(self.world.state.unwrapped_s_m, cfg.control_dt_s, STUCK_RULE)

    def seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def reset_cars(self, ids: np.ndarray) -> None:
        """New episodes for cars ``ids``: on the racing line at a random point (or the start line), at the start
        speed."""
        ids = np.asarray(ids, dtype=np.int64)
        if len(ids) == 0:
            return
        cfg = self.config
        s0 = self.rng.uniform(0.0, self.track.length_m, len(ids)) if cfg.start == "random" else np.zeros(len(ids))
        speed = cfg.start_skill * self.profile.speed_at(self.ai_line.line_s_at(s0))
        self.world.reset(s_m=s0, lateral_m=self.observer.line.lateral_at(s0), speed_mps=speed, car_ids=ids)
        self.steps[ids] = 0
        self.return_[ids] = 0.0
        self.progress_m[ids] = 0.0
        self.stuck.reset(ids, self.world.state.unwrapped_s_m)

    def observation(self, ids: np.ndarray | None = None) -> dict[str, np.ndarray]:
        return self.observer(self.world.state, self.ids if ids is None else np.asarray(ids))

    def step(self, keys: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Apply the actors' outputs (n, 4); returns (next observation, reward (n,) float32, terminated (n,),
        truncated (n,), info: arrays over cars). No reset here: the caller resets finished cars."""
        cfg = self.config
        keys = np.asarray(keys, dtype=np.float64)
        if keys.shape != (cfg.n_cars, 4):
            raise PixelRacingError(
                f"actions must have shape ({cfg.n_cars}, 4) [accelerate, left, right, brake], got {keys.shape}"
            )
        action = keys_to_action(keys)
        s_prev = self.world.state.s_m.copy()
        events = self.world.step(action[:, 0], action[:, 1])
        st = self.world.state
        ids = self.ids
        obs = self.observation()
        _, dist = self.observer.goal(st, ids)
        crash = self.observer.crash_state(st, ids)
        forward = st.vehicle.vx_mps
        reward = pixel_reward(forward, dist, crash, cfg.line_distance_alpha, cfg.crash_penalty_beta)
        self.steps += 1
        self.return_ += reward
        self.progress_m += self.track.progress_delta(s_prev, st.s_m)
        stuck = np.zeros(cfg.n_cars, dtype=bool)
        stuck[self.stuck.update(st.unwrapped_s_m)] = True
        terminated = dist > cfg.max_line_distance_m
        if cfg.terminate_on_crash:
            terminated |= crash != CRASH_NONE
        if cfg.terminate_when_stuck and not cfg.truncate_when_stuck:
            terminated |= stuck
        truncated = ((self.steps >= cfg.max_episode_steps) | (stuck & cfg.truncate_when_stuck)) & ~terminated
        info = {
            "crash_state": crash,
            "line_distance_m": dist,
            "forward_speed_mps": forward.copy(),
            "lap_distance_m": st.s_m.copy(),
            "progress_m": self.progress_m.copy(),
            "laps_completed": st.laps_completed.copy(),
            "lap_completed": events.lap_completed.copy(),
            "lap_time_s": events.lap_time_s.copy(),
            "wall_contact_s": st.wall_contact_time_s.copy(),
            "stuck": stuck,
            "episode_return": self.return_.copy(),
            "episode_steps": self.steps.copy(),
        }
        return obs, reward.astype(np.float32), terminated, truncated, info

    def close(self) -> None:
        self.observer.close()


# ------------------------------------------------------------------------------------------------ gymnasium


def _config(kwargs: dict[str, Any], n_cars: int) -> PixelRacingConfig:
    fields = set(PixelRacingConfig.__dataclass_fields__)
    unknown = set(kwargs) - fields
    if unknown:
        raise TypeError(f"unknown argument(s) {sorted(unknown)}; accepted: {sorted(fields)}")
    return PixelRacingConfig(**{**kwargs, "n_cars": n_cars})


class PixelRacing(gym.Env):
    """One car learning to race from pixels with a privileged critic (the Project CARS 2 DDPG paper).

    ## Action Space
    ``Box([0, -1, -1, 0], [1, 1, 1, 1], float32)``: the actor's four outputs ``[accelerate, left, right, brake]``
    (the paper's keys). Each is the share of the 0.1 s step its key is held (the paper's 0.1-1.5 s key presses as a
    duty cycle): accelerate and brake directly, left and right as ``(t + 1) / 2`` of their tanh outputs. They become
    our action by ``steering = (left - right) * pi/6`` rad and ``omega = accelerate - brake``
    (:func:`keys_to_action`). v1: ``Box(-1, 1, (4,), float32)``, mapped linearly onto those ranges inside the
    environment (accelerate and brake ``(a + 1) / 2``: -1 releases the key, +1 holds it the whole step; left and right
    as they are; :func:`physical_keys`).

    ## Observation Space
    ``Dict(image=Box(0, 255, (89, 120, 3), uint8), motion=Box(15,), goal=Box(3,))``:

    - ``image`` (the actor's): the driver's view from the offscreen renderer, rendered at 89x120 (``render_scale``
      times that, box-averaged, when asked), rows 0-29 (the top third) black. Left out with ``frames=False``.
    - ``motion`` (the critic's, float32, SI units, raw): position x, y, z (m; z = 0), orientation roll, pitch, yaw
      (rad), body-frame velocity vx, vy, vz (m/s; vz = 0), angular rates roll, pitch, yaw (rad/s), body-frame
      acceleration ax, ay, az without gravity (m/s^2; az = 0).
    - ``goal`` (the critic's): the racing-line point matched to the car (the line's point on the car's
      cross-section of the track), world x, y, z in m (``goal_frame="world"``, the paper) or its offset from the
      car in the body frame (``goal_frame="body"``). The line is the car's minimum-curvature line
      (``racing_line="car"``) or the racetrack-database's (``racing_line="reference"``, its circuits only).

    v0 declares ``motion`` and ``goal`` ``(-inf, inf)``; v1 bounds a world-frame goal's x and y by the racing
    line's bounding box (:meth:`PixelObserver.bounded_space`); nothing else has a bound by definition.

    ## Rewards
    ``r = V - alpha |d| - beta crashState``: V the forward (body-frame x) speed in m/s, d the distance from the car
    to its racing-line point in m, alpha ``line_distance_alpha`` (default 1 (m/s)/m: a metre off the line costs
    as much as 1 m/s), beta ``crash_penalty_beta`` (default 0, the paper's simple reward; the alternative with a
    positive beta charges beta per crashState unit on every step with a crash: with ``terminate_on_crash`` off the
    episode goes on, otherwise that step ends it).

    crashState, as the paper's enum, set from our simulator (the most severe that applies): 1 off-track (the car's
    centre beyond the painted edge line, on the kerb or shoulder), 2 large prop (a wall touched during the step),
    3 spinning (sideslip above ``spin_slip_deg``, 30 deg, above 3 m/s, or heading more than 90 deg from the track's
    direction), 4 rolling never (the model is planar).

    ## Starting State
    On the racing line, heading along the track, at 0.92 x the limit speed there (the built-in AI's speed): at a
    uniformly random point of the track (``start="random"``, default) or on the start/finish line
    (``start="line"``). ``reset(seed=k)`` makes the episodes reproducible.

    ## Episode End
    Termination, the paper's next-step rule: a non-zero crashState (``terminate_on_crash``), or a racing-line
    distance above ``max_line_distance_m`` (5 m), or stuck by the project's one rule (less than 5 m of progress in
    5 s; ``terminate_when_stuck``). Truncation after ``episode_s`` (300 s: three laps of Catalunya in a GT3), also
    ``max_episode_steps`` of the spec ``gymnasium.make`` gives (``episode_s / control_dt_s``, 3,000 by default), and
    when stuck with ``truncate_when_stuck`` (not in the paper; it replaces the stuck termination).

    ## Info
    ``crash_state``, ``line_distance_m``, ``forward_speed_mps``, ``lap_distance_m`` (the paper's
    mCurrentLapDistance), ``progress_m`` (this episode), ``laps_completed``, ``lap_completed``, ``lap_time_s`` (of
    the lap completed in this step, s; None in other steps), ``wall_contact_s``, ``stuck``, ``episode_return``,
    ``episode_steps``.

    ## Arguments
    Any field of :class:`PixelRacingConfig` but ``n_cars``: ``track`` (default ``Catalunya``), ``car`` (``gt3``),
    ``episode_s``, ``image_hw_px``, ``render_scale``, ``frames``, ``goal_frame``, ``racing_line``,
    ``line_distance_alpha``, ``crash_penalty_beta``, ``max_line_distance_m``, ``terminate_on_crash``,
    ``terminate_when_stuck``, ``truncate_when_stuck``, ``spin_slip_deg``, ``start``, ``start_skill``; and
    ``normalized_spaces`` (v1's spaces; its spec sets it). Several cars in one world: :class:`PixelRacingVectorEnv`, or
    ``gymnasium.make_vec(id, num_envs, vectorization_mode="vector_entry_point")``.

    ## Version History
    - v1: actions in [-1, 1] mapped onto the keys' ranges inside the environment; the goal bounded where known.
    - v0: first version (``info["lap_time_s"]`` None, no longer NaN, in steps without a lap: gymnasium's checker).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode: str | None = None, *, normalized_spaces: bool = False, **config: Any) -> None:
        self.config = _config(config, 1)
        self.render_mode = render_mode
        self.normalized_spaces = bool(normalized_spaces)
        self.action_space = action_space(self.normalized_spaces)
        self.core = PixelRacingCore(self.config)
        observer = self.core.observer
        self.observation_space = observer.bounded_space() if self.normalized_spaces else observer.space

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.core.seed(seed)
        self.core.reset_cars(np.array([0]))
        return take(self.core.observation(), 0), {}

    def step(self, action):
        keys = physical_keys(np.asarray(action, dtype=np.float64)[None, :], self.normalized_spaces)
        obs, reward, terminated, truncated, info = self.core.step(keys)
        single = {k: v[0].item() if np.ndim(v[0]) == 0 else v[0] for k, v in info.items()}
        if math.isnan(single["lap_time_s"]):
            single["lap_time_s"] = None  # not NaN: an info must equal itself (gymnasium's determinism check)
        return take(obs, 0), float(reward[0]), bool(terminated[0]), bool(truncated[0]), single

    def render(self):
        """The actor's frame (89, 120, 3) uint8, masked."""
        return self.core.observer.frames(self.core.world.state, np.array([0]))[0]

    def close(self) -> None:
        self.core.close()


class PixelRacingVectorEnv(VectorEnv):
    """``n_cars`` PixelRacing sub-environments in one world, one renderer call per step; finished ones reset in the
    same step (``AutoresetMode.SAME_STEP``: their returned observation starts the new episode, the last one of the
    old episode is in ``info["final_obs"]``)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self, n_cars: int = 4, seed: int | None = None, *, normalized_spaces: bool = False, **config: Any
    ) -> None:
        self.config = _config(config, n_cars)
        self.core = PixelRacingCore(self.config, seed=seed)
        self.num_envs = n_cars
        self.normalized_spaces = bool(normalized_spaces)
        self.single_action_space = action_space(self.normalized_spaces)
        observer = self.core.observer
        self.single_observation_space = observer.bounded_space() if self.normalized_spaces else observer.space
        self.action_space = batch_space(self.single_action_space, n_cars)
        self.observation_space = batch_space(self.single_observation_space, n_cars)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.core.seed(seed)
        self.core.reset_cars(self.core.ids)
        return self.core.observation(), {}

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.core.step(physical_keys(actions, self.normalized_spaces))
        done = terminated | truncated
        if done.any():
            ids = np.flatnonzero(done)
            final_obs = np.empty(self.num_envs, dtype=object)
            for i in ids:  # a reset, not the per-step path
                final_obs[i] = {k: v[i].copy() for k, v in obs.items()}  # a copy: the row is overwritten below
            info.update(final_obs=final_obs, _final_obs=done)
            self.core.reset_cars(ids)
            fresh = self.core.observation(ids)
            for key in obs:
                obs[key][ids] = fresh[key]
        return obs, reward, terminated, truncated, info

    def close_extras(self, **kwargs: Any) -> None:
        self.core.close()
