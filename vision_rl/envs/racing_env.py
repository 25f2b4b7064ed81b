"""Single-agent gymnasium environments: ``vision_rl/TimeTrial-v1``/``-v2`` and ``vision_rl/Overtaking-v1``/``-v2``
(v2: normalized actions and bounded observations, see :class:`TimeTrial`)."""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from vision_rl.envs.core import RacingConfig, RacingCore
from vision_rl.envs.scaling import to_physical, unit_box
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD

#: The physical action's range, float64: ``[steering angle rad, omega]``; normalized actions map onto it.
ACTION_HIGH = np.array([ACTION_STEER_LIMIT_RAD, 1.0])
ACTION_LOW = -ACTION_HIGH


def action_space(normalized: bool = False) -> spaces.Box:
    """``[steering angle rad in [-pi/6, pi/6], omega in [-1, 1] (throttle > 0, brake < 0)]``, every environment's;
    ``Box(-1, 1, (2,))`` with ``normalized`` (mapped onto that range by :func:`physical_actions`)."""
    if normalized:
        return unit_box(2)
    return spaces.Box(ACTION_LOW.astype(np.float32), ACTION_HIGH.astype(np.float32), dtype=np.float32)


def physical_actions(actions: np.ndarray, normalized: bool) -> np.ndarray:
    """Actions (..., 2) as the core takes them: normalized ones mapped linearly onto ``[-pi/6, pi/6]`` rad and
    ``[-1, 1]`` (clipped first), physical ones as they are."""
    return to_physical(actions, ACTION_LOW, ACTION_HIGH) if normalized else np.asarray(actions)


def racing_config(defaults: dict[str, Any], config: dict[str, Any], n_groups: int) -> RacingConfig:
    """The :class:`RacingConfig` of an environment's defaults and arguments; an argument that is no field of it is
    refused, naming the accepted ones."""
    fields = {f.name for f in dataclasses.fields(RacingConfig)}
    unknown = set(config) - fields
    if unknown:
        raise TypeError(f"unknown argument(s) {sorted(unknown)}; accepted: {sorted(fields)}")
    if config.get("n_groups", n_groups) != n_groups:  # it was overridden silently: n_groups=0 made one group
        raise ValueError(
            f"n_groups={config['n_groups']!r}: the environment sets it ({n_groups}); for several groups give "
            "num_envs to gymnasium.make_vec"
        )
    return RacingConfig(**{**defaults, **config, "n_groups": n_groups})


class _RacingEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}
    _defaults: dict[str, Any] = {}

    def __init__(self, render_mode: str | None = None, *, normalized_spaces: bool = False, **config: Any) -> None:
        self.config = racing_config(self._defaults, config, n_groups=1)
        self.render_mode = render_mode
        self.normalized_spaces = bool(normalized_spaces)
        self.action_space = action_space(self.normalized_spaces)
        self._core: RacingCore | None = None
        observer = self.core.observer
        self.observation_space = observer.bounded_space() if self.normalized_spaces else observer.space

    @property
    def core(self) -> RacingCore:
        if self._core is None:
            self._core = RacingCore(self.config)
        return self._core

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.core.seed(seed)
        self.core.reset_groups(np.array([0]))
        return self._single(self.core.observation()), {}

    def step(self, action):
        action = np.asarray(action)
        if action.shape != self.action_space.shape:  # numpy's broadcast message names neither the action nor its space
            raise ValueError(
                f"an action is [steering, pedal], shape {self.action_space.shape}: got shape {action.shape}"
            )
        actions = physical_actions(action[None, :], self.normalized_spaces)
        obs, reward, terminated, truncated, infos = self.core.step(actions, autoreset=False)
        return self._single(obs), float(reward[0]), bool(terminated[0]), bool(truncated[0]), infos[0]

    @staticmethod
    def _single(obs):
        if isinstance(obs, dict):
            return {k: v[0] for k, v in obs.items()}
        return obs[0]

    def render(self):
        """The driver's view (H, W, 3) uint8 from the offscreen renderer."""
        core = self.core
        return core.observer.frames(core.world.state, core.ego_ids)[0]

    def close(self) -> None:
        if self._core is not None:
            self._core.observer.close()
        self._core = None


class TimeTrial(_RacingEnv):
    """One car alone on a walled track, racing the clock (the GT Sport time trial of both Sony papers).

    ## Action Space
    ``Box([-pi/6, -1], [pi/6, 1], float32)`` (v1): the front-wheel steering angle command in rad (+ left) and omega,
    throttle (> 0) or brake (< 0) in [-1, 1]. Steering is rate-limited and both commands pass a short actuator lag.
    v2: ``Box(-1, 1, (2,), float32)``, mapped linearly onto those ranges inside the environment (-1: -pi/6 rad and
    full brake, +1: +pi/6 rad and full throttle; :func:`physical_actions`).
    Not in the papers: with ``steer_action="rate"`` the first entry asks for a change of the steering command
    instead (``entry / (pi/6)`` of the most the car's steering rate limit turns the wheel in one control step); with
    ``"speed_scaled"`` for ``entry / (pi/6)`` of the angles usable at the car's speed, ``min(pi/6, 6 L g / v^2)``;
    with ``"rate_scaled"`` for a change as in ``rate``, the command clipped to that range.

    ## Observation Space
    ``observation="state"`` (default): ``Box(38,)`` float32, the privileged observation of Fuchs et al.: 13 edge
    distances at -90..+90 deg (m), minimum distances to the left and right walls (m), signed distance to the centre
    line (m, + left), heading angle to the centre line (rad), centre-line curvature 1.0-2.8 s ahead at the current
    speed (10, 1/m), then the 11 dedicated features (body velocity, body acceleration, angular velocity, wall
    flag, previous steering). Normalised (z-score with statistics sampled once from the disrupted built-in AI and
    cached) unless ``normalize=False``; names in ``vision_rl.envs.observations.STATE_OBS_NAMES``.
    ``observation="vision"``: ``Dict(image=Box(280, 470, 3) uint8, features=Box(11,) float32)``, the driver's-view
    frame from the offscreen renderer and the raw dedicated features. ``frame_delay_s`` (default 0; the vision
    paper's frames lag by 4 frames at 60 Hz, 0.067 s) renders the frame of the poses that long ago, interpolated
    between control steps; the features stay current.
    v1 declares every vector entry ``(-inf, inf)``; v2 gives the bounds the features have by definition, normalised
    as the observation is (:func:`vision_rl.envs.observations.feature_bounds`: edge rays, wall distances, heading
    angle, curvature, wall flag, previous steering), and ``(-inf, inf)`` where none is known (speeds,
    accelerations, rates, centre-line offset).

    ## Rewards
    ``r = (cp_t - cp_{t-1}) - c_w * wall * |v|^2``: centre-line progress in metres over the step (signed, so
    reversing is negative, and correct across the start/finish line) minus ``c_w`` (default 0.005) times the
    squared speed while touching a wall (overtaking paper Eq. 1, vision paper Eq. 3). Optional, not in the papers
    (off by default): ``- c_s * (change of the steering command / pi/6)^2`` with ``steer_change_penalty_c_s`` (with
    ``steer_change_penalty_scale='usable'`` the change is measured against the angle usable at the car's speed),
    against the bang-bang steering SAC learns on the papers' reward; ``- c_o * off * |v|^2`` with
    ``off_track_penalty_c_o``, ``off`` when the side of the car's body ends the step over the painted edge line,
    against running wide into the wall.

    ## Starting State
    A uniformly random point of the track, on the built-in AI's racing line, heading along the track at the AI's
    speed there (the papers start each 100 s trial at a new point). ``reset(seed=k)`` gives the same episodes as
    group 0 of a vector environment seeded with k (:class:`vision_rl.envs.core.RacingCore`'s seeding). Not in the
    papers (off by default): with ``terminate_when_stuck``, ``restart_before_stuck_share`` of the starts lie up to
    ``restart_before_stuck_m`` before a place where the car recently got stuck.

    ## Episode End
    Truncation after ``episode_s`` (100 s = 1,000 steps at 10 Hz), also ``max_episode_steps`` of the spec
    ``gymnasium.make`` gives (``episode_s / control_dt_s``, from the arguments it is given). No termination unless
    asked for:
    ``terminate_when_stuck=True`` terminates an episode when the car is stuck by the project's one rule
    (``vision_rl.sim.fleet.STUCK_RULE``: less than 5 m of progress in 5 s).

    ## Info
    ``lap_times_s`` (completed laps of this episode), ``lap_completed``, ``progress_m``, ``wall_contact_s``,
    ``speed_mps``, ``episode_time_s``.

    ## Arguments
    Any field of :class:`vision_rl.envs.core.RacingConfig`: ``track`` (built-in name, ``random:SEED``, CSV path),
    ``car``, ``observation``, ``control_dt_s``, ``episode_s``, ``wall_penalty_c_w``, ``steer_change_penalty_c_s``,
    ``steer_change_penalty_scale``, ``off_track_penalty_c_o``,
    ``steer_action``, ``terminate_when_stuck``, ``restart_before_stuck_share``, ``restart_before_stuck_m``,
    ``normalize``, ``image_hw_px``, ``frame_delay_s``; and ``normalized_spaces`` (v2's spaces; its spec sets it).
    For 20 cars in one world use :func:`vision_rl.envs.make_vector_env`, or ``gymnasium.make_vec(id, num_envs,
    vectorization_mode="vector_entry_point")``.

    ## Version History
    - v2: actions in [-1, 1] mapped onto the physical ranges inside the environment; finite observation bounds where
      known.
    - v1: 0.02 s world ticks, per-group seeding, fixed normalisation, the one stuck rule (docs/notes/envs.md).
    - v0: first version.
    """

    _defaults = {"scenario": "time_trial"}


class Overtaking(_RacingEnv):
    """An ego car behind built-in AI opponents of its own collision group (the overtaking paper).

    ## Action Space
    As :class:`TimeTrial`.

    ## Observation Space
    ``Box(96,)`` float32 (overtaking paper, Table I): body velocity (3, m/s), body acceleration (3, m/s^2),
    heading angle to the centre line (rad), 72 lidar beams over -108..+108 deg with a 20 m range hitting walls and
    cars (m), previous steering command (rad), wall flag, car flag, centre-line curvature 0.2-3.0 s ahead (14,
    1/m). Normalised as in the paper: z-score, except the lidar, min-max scaled to [0, 1]. v2 bounds the entries
    that have bounds by definition (the lidar to [0, 1], heading angle, previous steering, flags, curvature), as
    :class:`TimeTrial` v2.

    ## Rewards
    Eq. 2: the racing reward, minus ``c_c * car * |v|^2`` while touching a car, plus for every opponent within
    ``c_d`` metres of progress ``c_r * (dcp_i(t-1) - dcp_i(t))``, ``dcp_i = cp_i - cp_ego`` wrapped to half a lap.

    ## Starting State
    The ego at a random point on the racing line at the AI's speed; opponents ahead of it on the line, spaced by
    the scenario: ``stage1`` none, ``stage2`` one 200 m ahead, ``setting_a``/``setting_b`` five, 50/200 m apart
    (the paper's evaluation), driving at skills drawn from ``opponent_skill`` and keeping a gap to cars ahead.

    ## Episode End
    As :class:`TimeTrial`.

    ## Info
    As :class:`TimeTrial`, plus the paper's four metrics ``travel_time_s``, ``travel_distance_m``,
    ``car_contact_s``, ``wall_contact_s`` and ``overtaken``, the number of opponents passed.

    ## Arguments
    As :class:`TimeTrial`, plus ``scenario`` (default ``setting_a``), ``car_penalty_c_c``, ``overtake_gain_c_r``,
    ``detection_range_c_d_m`` and ``opponent_skill``. The paper raced the Audi TT Cup: ``car="tt_cup"``.

    ## Version History
    - v2: as TimeTrial v2 (actions in [-1, 1], finite observation bounds where known).
    - v1: as TimeTrial v1; opponents are driven by the one AI-fleet runner (``vision_rl.sim.fleet.AIFleet``).
    - v0: first version.
    """

    _defaults = {"scenario": "setting_a", "observation": "overtaking"}
