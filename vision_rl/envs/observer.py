"""The one place where a world state becomes an observation, in training and evaluation alike.

An :class:`Observer` turns the raw state of chosen cars of a world into one of the observations of
:mod:`vision_rl.envs.observations`: ``state`` (38-D), ``overtaking`` (96-D) or ``vision``. It owns what that takes:
the wall ray caster, the offscreen renderer (vision, created on first use), the frozen encoder (vision, when given)
and the normalisation. ``vision`` without an encoder gives the gymnasium Dict ``{image, features}``; with one, the
vector ``[embedding (rep_dim), 11 dedicated features]`` that Phase 2's policies read, followed, with ``critic_state``,
by the 38-D ``state`` observation for an asymmetric critic.

The encoder is any callable from frames (n, H, W, 3) uint8 to (n, rep_dim) (a torch tensor or an array) with a
``rep_dim`` attribute: this layer never imports torch.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from vision_rl.envs import observations as obs_lib
from vision_rl.envs.scaling import bounded_box
from vision_rl.sim import sensors
from vision_rl.sim.track import Track
from vision_rl.sim.vehicle import VehicleParams
from vision_rl.sim.world import WorldState

#: The vision paper's frames reach the agent 4 frames (67 ms at 60 Hz) behind the game state it acts on (section 3).
PAPER_FRAME_DELAY_S = 4 / 60


class PoseHistory:
    """Every car's pose (x, y, yaw) at the last control steps, to render frames as they were ``delay_s`` ago.

    Between two control steps the pose is interpolated linearly (yaw along the shorter arc): at 40 m/s in a 100 m
    radius bend the chord of a 0.1 s step leaves the arc by at most v^2 dt^2 / (8 r) = 2 cm. Before a car has
    that much history (an episode's first steps) its oldest known pose stands in.
    """

    def __init__(self, delay_s: float, control_dt_s: float) -> None:
        if not (np.isfinite(delay_s) and 0.0 <= delay_s <= 1.0):
            raise ValueError(f"frame delay must be in [0, 1] s, got {delay_s}")
        if not (np.isfinite(control_dt_s) and control_dt_s > 0.0):
            raise ValueError(f"control step must be > 0 s, got {control_dt_s}")
        self.delay_s = float(delay_s)
        self.steps_back = self.delay_s / control_dt_s
        self.poses: np.ndarray | None = None  # (depth, 3, n_cars), newest first

    @staticmethod
    def _pose(state: WorldState) -> np.ndarray:
        v = state.vehicle
        return np.stack([v.x_m, v.y_m, v.yaw_rad])

    def restart(self, state: WorldState, car_ids: np.ndarray | None = None) -> None:
        """Forget the past of ``car_ids`` (all: None): placed cars have no history but their pose now."""
        now = self._pose(state)
        if self.poses is None or car_ids is None:
            self.poses = np.repeat(now[None], int(np.floor(self.steps_back)) + 2, axis=0)
        else:
            self.poses[:, :, car_ids] = now[None, :, car_ids]

    def remember(self, state: WorldState) -> None:
        """Record the poses after a control step."""
        if self.poses is None:
            self.restart(state)
            return
        self.poses = np.roll(self.poses, 1, axis=0)
        self.poses[0] = self._pose(state)

    def delayed(self, state: WorldState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x_m, y_m, yaw_rad) of every car ``delay_s`` before the last remembered step."""
        if self.poses is None:
            self.restart(state)
        i = int(np.floor(self.steps_back))
        f = self.steps_back - i
        newer, older = self.poses[i], self.poses[i + 1]
        xy = (1.0 - f) * newer[:2] + f * older[:2]
        turn = np.angle(np.exp(1j * (older[2] - newer[2])))
        return xy[0], xy[1], newer[2] + f * turn


def in_batches_of(size: int, fn, rows: np.ndarray) -> np.ndarray:
    """``fn`` over ``rows`` in batches of exactly ``size`` rows (the last padded with copies of its last row), joined.

    A network's matrix products round differently (in the last bit) by batch size and by the alignment of the batch
    in memory, and a policy's laps are chaotic in the last bit of its command: each batch is a fresh array of one
    size, so the k-th row gives the same result however many rows follow it, fewer than ``size`` included.
    """
    n = len(rows)
    padded = np.concatenate([rows, np.repeat(rows[-1:], -n % size, axis=0)])
    return np.concatenate([np.asarray(fn(padded[i : i + size].copy())) for i in range(0, len(padded), size)])[:n]


class Observer:
    """Observations of cars ``ids`` of a world on ``track`` with cars ``car`` in collision ``groups``.

    Args:
        kind: ``state``, ``overtaking`` or ``vision``.
        normalizer: applied to the vector (state, overtaking, vision with an encoder); None: raw physical units.
        encoder: vision only: the frozen frame encoder; None gives the Dict of frame and raw features.
        image_hw_px: vision frame size, (height, width) px.
        batch_cars: vision: render and embed the frames in batches of this many cars (:func:`in_batches_of`; the
            renderer's views per pass, whose layout sets a view's pixels, even with fewer cars), so that a car's
            observation does not change with the number of cars after it; 0: all at once, one view per collision
            group.
        critic_state: vision with an encoder: append the raw 38-D ``state`` observation to the vector
            (``RacingConfig.critic_state``).
    """

    def __init__(
        self,
        kind: str,
        track: Track,
        car: VehicleParams,
        groups: np.ndarray,
        normalizer: obs_lib.ObsNormalizer | None = None,
        encoder=None,
        image_hw_px: tuple[int, int] = (280, 470),
        batch_cars: int = 0,
        critic_state: bool = False,
    ) -> None:
        self.kind = obs_lib.ObservationKind.of(kind)
        if encoder is not None and not self.kind.sees_frames:
            raise ValueError(f"the {kind!r} observation takes no encoder")
        self.track = track
        self.car = car
        self.groups = np.asarray(groups)
        self.normalizer = normalizer
        self.encoder = encoder
        self.image_hw_px = (int(image_hw_px[0]), int(image_hw_px[1]))
        if batch_cars < 0:
            raise ValueError(f"batch_cars must be >= 0, got {batch_cars}")
        self.batch_cars = int(batch_cars)
        if critic_state and (not self.kind.sees_frames or encoder is None):
            raise ValueError("critic_state appends the state observation to the vision vector: it needs an encoder")
        self.critic_state = bool(critic_state)
        self.caster = sensors.WallRayCaster(track)
        self.renderer = None
        self.pose_history: PoseHistory | None = None

    def delay_frames(self, delay_s: float, control_dt_s: float) -> None:
        """Render vision frames ``delay_s`` behind the state (0: none); the dedicated features stay current.
        Whoever steps the world then calls :meth:`remember` after each control step and :meth:`restart` after
        placing cars."""
        self.pose_history = PoseHistory(delay_s, control_dt_s) if delay_s > 0 else None

    def remember(self, state: WorldState) -> None:
        if self.pose_history is not None:
            self.pose_history.remember(state)

    def restart(self, state: WorldState, car_ids: np.ndarray | None = None) -> None:
        if self.pose_history is not None:
            self.pose_history.restart(state, car_ids)

    @property
    def dim(self) -> int | None:
        """Length of the observation vector (None: the vision Dict)."""
        if not self.kind.sees_frames:
            return self.kind.vector_dim()
        return None if self.encoder is None else self.kind.vector_dim(int(self.encoder.rep_dim), self.critic_state)

    @property
    def space(self) -> spaces.Space:
        """The gymnasium space of one car's observation."""
        if self.dim is None:
            height, width = self.image_hw_px
            return spaces.Dict(
                {
                    "image": spaces.Box(0, 255, (height, width, 3), dtype=np.uint8),
                    "features": spaces.Box(-np.inf, np.inf, (len(sensors.DEDICATED_NAMES),), dtype=np.float32),
                }
            )
        return spaces.Box(-np.inf, np.inf, (self.dim,), dtype=np.float32)

    def bounded_space(self) -> spaces.Space:
        """:attr:`space` with the bounds its features have by definition
        (:func:`~vision_rl.envs.observations.feature_bounds`), normalised as the observation is; -inf/inf where
        none is known (the newer environment versions' observation space)."""
        dedicated = obs_lib.feature_bounds(sensors.DEDICATED_NAMES, self.track)
        if self.dim is None:
            return spaces.Dict({"image": self.space["image"], "features": bounded_box(*dedicated)})
        names = self.kind.names
        if self.kind.sees_frames:
            state_names = obs_lib.STATE_OBS_NAMES if self.critic_state else ()
            names = ("",) * int(self.encoder.rep_dim) + sensors.DEDICATED_NAMES + state_names
        low, high = obs_lib.feature_bounds(names, self.track)
        if self.normalizer is not None:
            offset, scale = self.normalizer.offset, self.normalizer.scale
            low, high = (low - offset) / scale, (high - offset) / scale
        return bounded_box(low, high)

    def frames(self, state: WorldState, ids: np.ndarray) -> np.ndarray:
        """Driver's-view frames (len(ids), H, W, 3) uint8 of cars ``ids``; each sees the cars of its group."""
        if self.renderer is None:
            try:
                from vision_rl.render import RenderConfig, Renderer
            except ImportError as exc:
                raise RuntimeError(
                    "the vision observation needs the renderer (vision_rl.render: moderngl with EGL); "
                    f"it could not be imported: {exc}"
                ) from exc
            height, width = self.image_hw_px
            views = self.batch_cars or len(np.unique(self.groups))
            self.renderer = Renderer(
                self.track,
                RenderConfig(width_px=width, height_px=height, max_views=views),
                car_length_m=self.car.length_m,
                car_width_m=self.car.width_m,
            )
        if self.pose_history is not None:
            x_m, y_m, yaw_rad = self.pose_history.delayed(state)
        else:
            x_m, y_m, yaw_rad = state.vehicle.x_m, state.vehicle.y_m, state.vehicle.yaw_rad
        return self.renderer.render(x_m, y_m, yaw_rad, view_ids=np.asarray(ids), groups=self.groups)

    def _features(self, state: WorldState, ids: np.ndarray) -> np.ndarray:
        v = state.vehicle
        vehicle_ids = type(v)(*(a[ids] for a in v))
        return sensors.dedicated_features(vehicle_ids, state.wall_contact[ids], state.prev_steer_cmd_rad[ids])

    def raw(self, state: WorldState, ids: np.ndarray) -> np.ndarray:
        """The observation vectors (len(ids), dim) before normalisation, float64."""
        ids = np.asarray(ids)
        if self.kind is obs_lib.ObservationKind.STATE:
            return obs_lib.state_observation(self.track, self.caster, state, ids)
        if self.kind is obs_lib.ObservationKind.OVERTAKING:
            return obs_lib.overtaking_observation(
                self.track, self.caster, state, ids, self.car.length_m, self.car.width_m, self.groups
            )
        if self.encoder is None:
            raise ValueError("the vision observation is a vector only with an encoder")
        vector = self.embed(self.frames(state, ids), self._features(state, ids))
        if self.critic_state:
            return np.hstack([vector, obs_lib.state_observation(self.track, self.caster, state, ids)])
        return vector

    def embed(self, images: np.ndarray, features: np.ndarray) -> np.ndarray:
        """(n, rep_dim + 11) float64 from frames (n, H, W, 3) uint8 and raw dedicated features (n, 11)."""
        embedding = in_batches_of(self.batch_cars, self._encode, images) if self.batch_cars else self._encode(images)
        return np.hstack([embedding.astype(np.float64), np.asarray(features, dtype=np.float64)])

    def _encode(self, images: np.ndarray) -> np.ndarray:
        embedding = self.encoder(images)
        return embedding.cpu().numpy() if hasattr(embedding, "cpu") else np.asarray(embedding)

    def __call__(self, state: WorldState, ids: np.ndarray) -> np.ndarray | dict[str, np.ndarray]:
        """The observations of cars ``ids``: normalised float32 vectors (len(ids), dim), or the vision Dict."""
        ids = np.asarray(ids)
        if self.kind.sees_frames and self.encoder is None:
            return {"image": self.frames(state, ids), "features": self._features(state, ids).astype(np.float32)}
        raw = self.raw(state, ids)
        return self.normalizer(raw) if self.normalizer is not None else raw.astype(np.float32)

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None
