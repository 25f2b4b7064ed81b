"""A person as a driver of the lap-time protocol: keyboard or gamepad, a pygame window, the run kept as
demonstrations.

It takes a new command every 0.1 s and holds it, as the environments do, so that what it records is the
environments' transitions. Its rates, the keys and the gamepad's axes: docs/notes/evaluation.md. pygame is imported
only when a window is opened (the ``play`` extra).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vision_rl.envs.observer import Observer
from vision_rl.envs.rewards import racing_reward
from vision_rl.sim.fleet import AI_CONTROL_DT_S
from vision_rl.sim.vehicle import ACTION_STEER_LIMIT_RAD
from vision_rl.sim.world import World, WorldState

#: How fast a held steering key turns the commanded wheel angle, rad/s: full lock (0.52 rad) in 0.35 s, as quick
#: as the car's own actuator allows (1.5 rad/s), so the key never lags the car.
KEY_STEER_RATE_RADPS = 1.5
#: Below this speed a key or a full stick asks for the whole lock; above it the lock falls as 1/v (the lateral
#: acceleration a full lock would ask for then stays near what 12 m/s at full lock gives), m/s.
FULL_LOCK_BELOW_MPS = 12.0
#: The driver takes a new command this often and holds it, s: the environments' control step.
COMMAND_DT_S = 0.1
#: c_w of the recorded reward (Eq. 1), as in the single-car race the demonstrations belong to.
WALL_PENALTY_C_W = 0.005
INPUTS = ("keyboard", "gamepad")


class HumanQuit(Exception):
    """The player ended the run (Escape or the window closed)."""


class NoDisplayError(ValueError):
    """No window (or no pygame, or no gamepad) to play with here."""


def speed_lock_rad(speed_mps: float) -> float:
    """The steering angle a full input asks for at ``speed_mps``: the action's lock up to
    :data:`FULL_LOCK_BELOW_MPS`, then falling as 1/v."""
    return ACTION_STEER_LIMIT_RAD * min(1.0, FULL_LOCK_BELOW_MPS / max(speed_mps, 1e-6))


@dataclass
class KeyboardSteering:
    """The commanded wheel angle of a keyboard driver (docs/notes/evaluation.md)."""

    steer_rad: float = 0.0

    def update(self, left: bool, right: bool, speed_mps: float, dt_s: float) -> float:
        lock = speed_lock_rad(speed_mps)
        target = lock * (float(left) - float(right))  # + left, as the action
        step = KEY_STEER_RATE_RADPS * dt_s
        self.steer_rad = float(np.clip(self.steer_rad + np.clip(target - self.steer_rad, -step, step), -lock, lock))
        return self.steer_rad


def gamepad_command(stick_x: float, right_trigger: float, left_trigger: float, speed_mps: float) -> np.ndarray:
    """``[steer rad, omega]`` from SDL axes: stick x in [-1, 1] (+ right), triggers in [-1 released, +1 pressed]."""
    steer = -float(np.clip(stick_x, -1.0, 1.0)) * speed_lock_rad(speed_mps)
    throttle = (float(np.clip(right_trigger, -1.0, 1.0)) + 1.0) / 2.0
    brake = (float(np.clip(left_trigger, -1.0, 1.0)) + 1.0) / 2.0
    return np.array([steer, throttle - brake])


def check_display() -> None:
    """Refuse, in one line, to open a window where none can be shown."""
    driver = os.environ.get("SDL_VIDEODRIVER", "")
    if not driver and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise NoDisplayError(
            "play needs a display: no DISPLAY or WAYLAND_DISPLAY is set (run it on a desktop, or set "
            "SDL_VIDEODRIVER=dummy for a scripted run without a window)"
        )


@dataclass
class Recording:
    """The run as the environments' transitions at :data:`COMMAND_DT_S` (unnormalised lists until the end)."""

    observations: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        """Complete transitions only (the last command's reward is known only after its step)."""
        n = len(self.rewards)
        starts = np.zeros(n, dtype=bool)
        starts[:1] = True
        return {
            "observations": np.asarray(self.observations[:n], dtype=np.float32).reshape(n, -1),
            "actions": np.asarray(self.actions[:n], dtype=np.float32).reshape(n, 2),
            # What a person applied is also their intended action: there is no separate label.
            "expert_actions": np.asarray(self.actions[:n], dtype=np.float32).reshape(n, 2),
            "rewards": np.asarray(self.rewards, dtype=np.float32),
            "episode_starts": starts,
        }


class HumanDriver:
    """A protocol driver for one car driven by a person (docs/notes/evaluation.md).

    Args:
        camera: ``chase`` or ``hood``.
        window_hw_px: window (height, width), px.
        input: ``keyboard`` or ``gamepad``.
        realtime: pace the run to the wall clock (off for scripted runs).
        observer: makes the recorded observation of each transition (e.g. the normalised ``overtaking`` one);
            None records nothing.
        events: where input events come from (default ``pygame.event.get``; tests script them).
    """

    control_dt_s = AI_CONTROL_DT_S

    def __init__(
        self,
        camera: str = "chase",
        window_hw_px: tuple[int, int] = (480, 800),
        input: str = "keyboard",
        realtime: bool = True,
        observer_factory: Callable[[World], Observer] | None = None,
        events: Callable[[], list] | None = None,
    ) -> None:
        if input not in INPUTS:
            raise ValueError(f"input must be one of {INPUTS}, got {input!r}")
        if camera not in ("chase", "hood"):
            raise ValueError(f"camera must be chase or hood, got {camera!r}")
        self.camera, self.window_hw_px, self.input, self.realtime = camera, window_hw_px, input, realtime
        self.observer_factory = observer_factory
        self.events = events
        self.recording = Recording()
        self.observer: Observer | None = None
        self._renderer = None
        self.hold_steps = round(COMMAND_DT_S / self.control_dt_s)
        self._pygame: Any = None

    @property
    def identity(self) -> dict[str, Any]:
        return {"driver": "human", "input": self.input, "camera": self.camera}

    # ---------------------------------------------------------------------------------------------- window
    def _open(self, world: World) -> None:
        check_display()
        try:
            import pygame
        except ImportError:
            raise NoDisplayError("play needs pygame: pip install 'vision_rl[play]'") from None

        from vision_rl.render import CameraConfig, RenderConfig, Renderer

        pygame.display.init()
        pygame.font.init()
        height, width = self.window_hw_px
        self._screen = pygame.display.set_mode((width, height))
        pygame.display.set_caption(f"vision-rl play: {world.track.name} / {world.car.name}")
        self._font = pygame.font.Font(None, 28)
        self._renderer = Renderer(
            world.track,
            RenderConfig(width_px=width, height_px=height, max_views=1, camera=CameraConfig(self.camera)),
            car_length_m=world.car.length_m,
            car_width_m=world.car.width_m,
        )
        self._pygame = pygame
        self._joystick = None
        if self.input == "gamepad":
            pygame.joystick.init()
            if pygame.joystick.get_count() == 0:
                raise NoDisplayError("--input gamepad: no gamepad is connected")
            self._joystick = pygame.joystick.Joystick(0)

    def reset(self, world: World, car_ids: np.ndarray) -> None:
        if len(car_ids) != 1:
            raise ValueError(f"a person drives one car, not {len(car_ids)} (use one protocol seed)")
        if self._pygame is None:
            self._open(world)
        self.world, self.car_id = world, int(car_ids[0])
        self.observer = self.observer_factory(world) if self.observer_factory is not None else None
        self.recording = Recording()
        self.keys: set[str] = set()
        self.steering = KeyboardSteering()
        self.command = np.zeros(2)
        self.calls = 0
        self.wall_any = False
        self.start_wall_s = time.perf_counter()

    def _read_input(self) -> None:
        pg = self._pygame
        names = {
            pg.K_UP: "up",
            pg.K_w: "up",
            pg.K_DOWN: "down",
            pg.K_s: "down",
            pg.K_LEFT: "left",
            pg.K_a: "left",
            pg.K_RIGHT: "right",
            pg.K_d: "right",
        }
        for event in self.events() if self.events is not None else pg.event.get():
            if event.type == pg.QUIT or (event.type == pg.KEYDOWN and event.key == pg.K_ESCAPE):
                raise HumanQuit("the player ended the run")
            if event.type in (pg.KEYDOWN, pg.KEYUP) and event.key in names:
                (self.keys.add if event.type == pg.KEYDOWN else self.keys.discard)(names[event.key])

    def _new_command(self, speed_mps: float) -> np.ndarray:
        if self._joystick is not None:
            js = self._joystick
            return gamepad_command(js.get_axis(0), js.get_axis(5), js.get_axis(2), speed_mps)
        steer = self.steering.update("left" in self.keys, "right" in self.keys, speed_mps, COMMAND_DT_S)
        return np.array([steer, float("up" in self.keys) - float("down" in self.keys)])

    def _draw(self, state: WorldState) -> None:
        pg, v = self._pygame, state.vehicle
        frame = self._renderer.render(v.x_m, v.y_m, v.yaw_rad, view_ids=np.array([self.car_id]))[0]
        pg.surfarray.blit_array(self._screen, frame.swapaxes(0, 1))
        i = self.car_id
        speed_kmh = 3.6 * math.hypot(v.vx_mps[i], v.vy_mps[i])
        lap_s = state.time_s[i] - (sum(self.world.lap_times_s[i]) if self.world.lap_times_s[i] else 0.0)
        text = f"{speed_kmh:5.0f} km/h   lap {state.laps_completed[i] + 1}   {lap_s:6.1f} s"
        self._screen.blit(self._font.render(text, True, (255, 255, 255)), (12, 10))
        pg.display.flip()

    # ------------------------------------------------------------------------------------------------- act
    def act(self, state: WorldState) -> np.ndarray:
        self._read_input()
        i = self.car_id
        speed_mps = math.hypot(state.vehicle.vx_mps[i], state.vehicle.vy_mps[i])
        if self.calls > 0:
            self.wall_any |= bool(state.wall_contact[i])
        if self.calls % self.hold_steps == 0:
            rec = self.recording
            if self.observer is not None:
                if rec.actions:  # the held command's step is over: its reward, as the environment gives it
                    progress = self.world.track.progress_delta(np.array([self._s_m]), state.s_m[i : i + 1])
                    reward = racing_reward(progress, np.array([self.wall_any]), np.array([speed_mps]), WALL_PENALTY_C_W)
                    rec.rewards.append(float(reward[0]))
                rec.observations.append(np.asarray(self.observer(state, np.array([i])))[0])
            self.command = self._new_command(speed_mps)
            if self.observer is not None:
                rec.actions.append(self.command.astype(np.float32))
            self._s_m = float(state.s_m[i])
            self.wall_any = False
        self._draw(state)
        self.calls += 1
        if self.realtime:
            ahead_s = self.calls * self.control_dt_s - (time.perf_counter() - self.start_wall_s)
            if ahead_s > 0:
                time.sleep(ahead_s)
        return self.command.astype(np.float32)[None, :].astype(np.float64)

    def close(self) -> None:
        if self.observer is not None:
            self.observer.close()
            self.observer = None
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._pygame is not None:
            self._pygame.display.quit()
            self._pygame = None
