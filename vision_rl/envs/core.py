"""The batched racing core behind every environment: M groups (an ego car and K built-in AI opponents each) in
one World, stepped together with no Python loop over cars.

Group g holds cars ``g * (K + 1)`` (its ego) to ``g * (K + 1) + K``; groups never touch each other, so 20
time-trial cars are 20 groups of one. The gymnasium environments (one group) and the vector environments (M
groups, same-step autoreset) are thin layers over :class:`RacingCore`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vision_rl.envs import observations as obs_lib
from vision_rl.envs.rewards import overtaking_reward, racing_reward, wrapped_gap_m
from vision_rl.sim import sensors
from vision_rl.sim.ai_driver import DEFAULT_SKILL, OPPONENT_SKILL_RANGE, AIDriver, Disruptor
from vision_rl.sim.driving import AI_CONTROL_DT_S, line_and_profile
from vision_rl.sim.track_library import load_track
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD, get_preset
from vision_rl.sim.world import StepEvents, World, WorldConfig

#: Scenario name -> (opponents per group, spacing between consecutive cars along the track in m).
SCENARIOS: dict[str, tuple[int, float]] = {
    "time_trial": (0, 0.0),
    "stage1": (0, 0.0),  # the curriculum's first stage: racing alone (overtaking paper, section III-C)
    "stage2": (1, 200.0),  # one built-in AI car 200 m ahead (section III-C)
    "setting_a": (5, 50.0),  # evaluation: five opponents ahead, 50 m apart (section IV-C)
    "setting_b": (5, 200.0),  # evaluation: five opponents ahead, 200 m apart
}
OBSERVATION_KINDS = ("state", "vision", "overtaking")


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
    stuck_timeout_s: float | None = None
    """If set, an episode terminates when the ego gained less than 1 m of progress over this many seconds."""
    normalize: bool = True
    """Normalise vector observations (z-score; lidar min-max) with cached statistics."""
    image_size_px: tuple[int, int] = (470, 280)
    """Width, height of the ``vision`` frames."""
    extra: dict = field(default_factory=dict, compare=False, hash=False)
    """Free-form notes carried with the config (not used by the environment)."""

    def __post_init__(self) -> None:
        if self.observation not in OBSERVATION_KINDS:
            raise ValueError(f"observation must be one of {OBSERVATION_KINDS}, got {self.observation!r}")
        if self.scenario not in SCENARIOS:
            raise ValueError(f"scenario must be one of {tuple(SCENARIOS)}, got {self.scenario!r}")
        if self.n_groups < 1:
            raise ValueError(f"n_groups must be >= 1, got {self.n_groups}")
        if self.episode_s < self.control_dt_s:
            raise ValueError("episode_s must cover at least one control step")

    @property
    def opponents(self) -> int:
        return SCENARIOS[self.scenario][0]

    @property
    def max_episode_steps(self) -> int:
        return round(self.episode_s / self.control_dt_s)


class RacingCore:
    """M groups racing in one world; observations, rewards and episode bookkeeping for the M egos."""

    def __init__(self, config: RacingConfig, seed: int | None = None) -> None:
        self.config = cfg = config
        self.track = load_track(cfg.track)
        self.car = get_preset(cfg.car)
        self.group_size = cfg.opponents + 1
        n_cars = cfg.n_groups * self.group_size
        self.ego_ids = np.arange(cfg.n_groups) * self.group_size
        self.groups = np.repeat(np.arange(cfg.n_groups), self.group_size)
        # The built-in AI is tuned to act every AI_CONTROL_DT_S: with opponents on track a control step is several
        # world steps, the AI acting at each and the egos' commands held (opponents acting at the agents' 10 Hz hit
        # walls for up to 83 s of a 120 s run, measured on the expressway). Alone, an ego needs one world step.
        self.ai_substeps = 1 if self.group_size == 1 else math.ceil(cfg.control_dt_s / AI_CONTROL_DT_S - 1e-9)
        world_config = WorldConfig(control_dt_s=cfg.control_dt_s / self.ai_substeps)
        self.world = World(self.track, self.car, n_cars, self.groups, world_config)
        self.line, self.profile = line_and_profile(self.track, self.car)
        self.rng = np.random.default_rng(seed)
        self.skill = np.full(n_cars, cfg.start_skill)
        self.unwrapped_at_reset = np.zeros(n_cars)
        self.ai = AIDriver(self.car, self.line, self.profile, n_cars, skill=self.skill, groups=self.groups)
        self.caster = sensors.WallRayCaster(self.track)
        self.renderer = None
        m = cfg.n_groups
        self.steps = np.zeros(m, dtype=np.int64)
        self.progress_m = np.zeros(m)
        self.recent_progress_m = np.zeros(m)
        self.recent_steps = np.zeros(m, dtype=np.int64)
        self.start_gap_m = np.zeros((m, cfg.opponents))
        self.gap_m = np.zeros((m, cfg.opponents))
        self.normalizer: obs_lib.ObsNormalizer | None = None
        if cfg.normalize and cfg.observation != "vision":
            self.normalizer = obs_lib.load_or_compute_normalizer(
                self.track, self.car.name, cfg.observation, self._sample_observations
            )

    # ------------------------------------------------------------------ placement
    def reset_groups(self, gids: np.ndarray) -> None:
        """New episodes for the groups ``gids``: random start point, AI speed, opponents ahead on the racing line."""
        cfg, k = self.config, self.group_size
        gids = np.asarray(gids, dtype=np.int64)
        if len(gids) == 0:
            return
        s0 = self.rng.uniform(0.0, self.track.length_m, len(gids))
        spacing = SCENARIOS[cfg.scenario][1]
        offsets = np.arange(k) * spacing
        car_ids = (gids[:, None] * k + np.arange(k)[None, :]).ravel()
        s = (s0[:, None] + offsets[None, :]).ravel()
        skill = np.full((len(gids), k), cfg.start_skill)
        if k > 1:
            skill[:, 1:] = self.rng.uniform(cfg.opponent_skill[0], cfg.opponent_skill[1], (len(gids), k - 1))
        self.skill[car_ids] = skill.ravel()
        self.ai.skill[car_ids] = skill.ravel()
        line_s = self.line.line_s_at(s)
        speed = self.skill[car_ids] * self.profile.speed_at(line_s)
        self.world.reset(s_m=s, lateral_m=self.line.lateral_at(s), speed_mps=speed, car_ids=car_ids)
        self.unwrapped_at_reset[car_ids] = self.world.state.unwrapped_s_m[car_ids]
        self.steps[gids] = 0
        self.progress_m[gids] = 0.0
        self.recent_progress_m[gids] = 0.0
        self.recent_steps[gids] = 0
        if k > 1:
            self.gap_m[gids] = self._gaps()[gids]
            self.start_gap_m[gids] = self.gap_m[gids]

    def _gaps(self) -> np.ndarray:
        """(M, K) wrapped progress gaps from each ego to its opponents, m (positive: the opponent is ahead)."""
        s = self.world.state.s_m.reshape(self.config.n_groups, self.group_size)
        return wrapped_gap_m(s[:, 1:], s[:, :1], self.track.length_m)

    # ------------------------------------------------------------------ observations
    def raw_observation(self, ids: np.ndarray | None = None) -> np.ndarray:
        """Vector observations (state or overtaking) of the egos (or the cars ``ids``), physical units."""
        ids = self.ego_ids if ids is None else ids
        st = self.world.state
        if self.config.observation == "overtaking":
            return obs_lib.overtaking_observation(
                self.track, self.caster, st, ids, self.car.length_m, self.car.width_m, self.groups
            )
        return obs_lib.state_observation(self.track, self.caster, st, ids)

    def observation(self) -> np.ndarray | dict[str, np.ndarray]:
        """The egos' observations as the environments return them (normalised vectors or a Dict for vision)."""
        if self.config.observation == "vision":
            return self._vision_observation()
        raw = self.raw_observation()
        return self.normalizer(raw) if self.normalizer is not None else raw.astype(np.float32)

    def _vision_observation(self) -> dict[str, np.ndarray]:
        if self.renderer is None:
            try:
                from vision_rl.render import RenderConfig, Renderer
            except ImportError as exc:
                raise RuntimeError(
                    "the vision observation needs the renderer layer (vision_rl.render: moderngl with EGL); "
                    f"it could not be imported: {exc}"
                ) from exc
            width, height = self.config.image_size_px
            self.renderer = Renderer(
                self.track, RenderConfig(width_px=width, height_px=height, max_views=len(self.ego_ids)),
                car_length_m=self.car.length_m, car_width_m=self.car.width_m,
            )  # fmt: skip
        st = self.world.state
        v = st.vehicle
        frames = self.renderer.render(v.x_m, v.y_m, v.yaw_rad, view_ids=self.ego_ids, groups=self.groups)
        ids = self.ego_ids
        features = sensors.dedicated_features(
            type(v)(*(a[ids] for a in v)), st.wall_contact[ids], st.prev_steer_cmd_rad[ids]
        )
        return {"image": frames, "features": features.astype(np.float32)}

    def _sample_observations(self, steps: int = 300) -> np.ndarray:
        """Raw observations of 20 disrupted built-in AI cars (the egos) over ``steps`` control steps: the states
        the normalisation statistics are computed from. Uses its own generator so env seeds do not change them."""
        saved_rng = self.rng
        self.rng = np.random.default_rng(12345)
        disruptor = Disruptor(len(self.skill), seed=12345)
        samples = []
        self.reset_groups(np.arange(self.config.n_groups))
        for _ in range(max(steps, 20 * steps // self.config.n_groups)):
            self.advance(disruptor=disruptor)
            samples.append(self.raw_observation())
        self.rng = saved_rng
        return np.concatenate(samples)

    # ------------------------------------------------------------------ stepping
    def advance(
        self, ego_steer_rad: np.ndarray | None = None, ego_omega: np.ndarray | None = None, disruptor=None
    ) -> StepEvents:
        """One control step of the world: ``ai_substeps`` world steps, the built-in AI driving every car at each
        (through ``disruptor`` when given) except the egos when their commands are given, which are held."""
        n = self.world.n_cars
        lap_completed, lap_time_s = np.zeros(n, dtype=bool), np.full(n, np.nan)
        for _ in range(self.ai_substeps):
            if ego_steer_rad is not None and self.group_size == 1:
                steer, omega = np.empty(n), np.empty(n)  # every car is an ego: the AI has nothing to drive
            else:
                steer, omega = self.ai.act(self.world.state)
                if disruptor is not None:
                    steer, omega = disruptor(steer, omega, self.world.model.config.control_dt_s)
            if ego_steer_rad is not None:
                steer[self.ego_ids], omega[self.ego_ids] = ego_steer_rad, ego_omega
            events = self.world.step(steer, omega)
            lap_completed |= events.lap_completed
            lap_time_s = np.where(events.lap_completed, events.lap_time_s, lap_time_s)
        return StepEvents(lap_completed, lap_time_s)

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
        events = self.advance(
            np.clip(actions[:, 0], -ACTION_STEER_LIMIT_RAD, ACTION_STEER_LIMIT_RAD), np.clip(actions[:, 1], -1.0, 1.0)
        )
        st = self.world.state
        ego = self.ego_ids
        progress = self.track.progress_delta(s_prev, st.s_m[ego])
        speed = np.hypot(st.vehicle.vx_mps[ego], st.vehicle.vy_mps[ego])
        reward = racing_reward(progress, st.wall_contact[ego], speed, cfg.wall_penalty_c_w)
        if self.group_size > 1:
            gap_now = self._gaps()
            reward = overtaking_reward(
                reward, st.car_contact[ego], speed, self.gap_m, gap_now, cfg.car_penalty_c_c,
                cfg.overtake_gain_c_r, cfg.detection_range_c_d_m,
            )  # fmt: skip
            self.gap_m = gap_now
        self.steps += 1
        self.progress_m += progress
        terminated = np.zeros(cfg.n_groups, dtype=bool)
        if cfg.stuck_timeout_s is not None:
            window = round(cfg.stuck_timeout_s / cfg.control_dt_s)
            self.recent_progress_m += progress
            self.recent_steps += 1
            full = self.recent_steps >= window
            terminated = full & (self.recent_progress_m < 1.0)
            self.recent_progress_m[full] = 0.0
            self.recent_steps[full] = 0
        truncated = (self.steps >= cfg.max_episode_steps) & ~terminated
        infos = [self._info(g, events) for g in range(cfg.n_groups)]
        obs = self.observation()
        done = terminated | truncated
        if autoreset and done.any():
            gids = np.flatnonzero(done)
            for g in gids:
                infos[g] = {"final_observation": _take(obs, g), "final_info": infos[g]}
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
