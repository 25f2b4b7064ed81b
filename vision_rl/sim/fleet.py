"""The built-in AI driving cars of one world, and the one rule that says a car is stuck.

:class:`AIFleet` is the single loop that steps AI-driven cars: capture, the environments (opponents, the
statistics rollout) and the built-in AI driver of the lap-time protocol all go through it. The AI acts every
:data:`AI_CONTROL_DT_S` whatever the caller's step; cars driven by someone else (an agent's ego car) keep their
commands over the caller's step. Stepping a world 5 x 0.02 s with held commands is bit-for-bit the same physics as
one 0.1 s step (the physics substep is 0.01 s either way), so the AI's rate does not change the other cars.

:data:`STUCK_RULE` is the one definition of "stuck" in the project. What follows from it is the caller's: the
protocol ends the car's run as a DNF, capture puts the car back on the racing line (it wants frames, not a race),
an environment may end the episode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vision_rl.sim.ai_driver import DEFAULT_SKILL, AIDriver, DisruptionParams, Disruptor
from vision_rl.sim.world import StepEvents, World

#: Control step of the built-in AI, s: it is tuned at 50 Hz (its steering feedforward leads by the 0.05 s actuator
#: lag plus half a step); at 10 Hz it completed no lap of the expressway (18-19 stuck cars at skills 0.92-1.0).
AI_CONTROL_DT_S = 0.02


def ai_ticks(control_dt_s: float) -> int | None:
    """How many of the AI's :data:`AI_CONTROL_DT_S` ticks make a step of ``control_dt_s`` seconds; None when the step
    is not a whole number (at least one) of them."""
    ticks = round(control_dt_s / AI_CONTROL_DT_S)
    return ticks if ticks >= 1 and abs(ticks * AI_CONTROL_DT_S - control_dt_s) < 1e-9 else None


@dataclass(frozen=True)
class StuckRule:
    """A car is stuck when it made less than ``min_progress_m`` of signed track progress over the last
    ``window_s`` (judged only once it has been on track that long since it was placed)."""

    window_s: float = 5.0
    """Length of the window, s. A car crawling at under 1 m/s for 5 s is not racing; a spin that ends facing
    the right way gets going again well within it."""
    min_progress_m: float = 5.0
    """Progress over the window below which the car is stuck, m (driving the wrong way is negative progress)."""

    def describe(self) -> str:
        return f"less than {self.min_progress_m:g} m of progress in {self.window_s:g} s"


STUCK_RULE = StuckRule()


class StuckDetector:
    """Applies a :class:`StuckRule` to cars stepped every ``dt_s``.

    A car is judged only on progress made since its last reset: a freshly placed car gets a whole window before it
    can be flagged again (judging it against a refilled history would flag it again at once, every step)."""

    def __init__(self, unwrapped_s_m: np.ndarray, dt_s: float, rule: StuckRule = STUCK_RULE) -> None:
        self.rule = rule
        self.window_steps = max(1, round(rule.window_s / dt_s))
        # One slot more than the window: after writing step k, slot (k + 1) % size holds step k - window.
        self._history_m = np.tile(np.asarray(unwrapped_s_m, dtype=np.float64), (self.window_steps + 1, 1))
        self._steps_since_reset = np.zeros(len(unwrapped_s_m), dtype=np.int64)
        self._step = 0

    def update(self, unwrapped_s_m: np.ndarray) -> np.ndarray:
        """Record one step's progress; returns the indices of the cars stuck now."""
        self._step += 1
        size = self.window_steps + 1
        self._history_m[self._step % size] = unwrapped_s_m
        self._steps_since_reset += 1
        progress_m = unwrapped_s_m - self._history_m[(self._step + 1) % size]
        judged = self._steps_since_reset >= self.window_steps
        return np.flatnonzero(judged & (progress_m < self.rule.min_progress_m))

    def reset(self, car_ids: np.ndarray, unwrapped_s_m: np.ndarray) -> None:
        """Cars ``car_ids`` were placed anew at ``unwrapped_s_m`` (all cars' values): restart their window."""
        self._history_m[:, car_ids] = unwrapped_s_m[car_ids]
        self._steps_since_reset[car_ids] = 0


class AIFleet:
    """The built-in AI driving every car of ``world`` (all but the held ones at each :meth:`advance`).

    Args:
        world: its control step must be :data:`AI_CONTROL_DT_S` or a whole fraction of it.
        line, profile: the car's racing line and QSS profile on the world's track
            (:func:`vision_rl.sim.driving.line_and_profile`).
        skill: (n_cars,) or scalar share of the reference speed each car aims for.
        disruption: random command offsets for data collection (None: clean driving).
        seed: seed of the disruptions.
    """

    def __init__(
        self,
        world: World,
        line,
        profile,
        skill: float | np.ndarray = DEFAULT_SKILL,
        disruption: DisruptionParams | None = None,
        seed: int = 0,
    ) -> None:
        dt = world.model.config.control_dt_s
        if dt > AI_CONTROL_DT_S + 1e-9:
            raise ValueError(f"the AI acts every {AI_CONTROL_DT_S} s; the world steps {dt} s")
        self.world = world
        self.line, self.profile = line, profile
        n = world.n_cars
        self.driver = AIDriver(world.car, line, profile, n, skill=skill, groups=world.model.groups)
        self.disruptor = Disruptor(n, disruption, seed=seed) if disruption is not None else None
        """Offsets added to the AI's commands (None: clean); a caller may swap it for a rollout."""
        self.last_steer_rad, self.mean_omega = np.zeros(n), np.zeros(n)
        """Every car's steering command at the last world step of the last stepped :meth:`advance` (rad) and its
        throttle/brake command averaged over that advance."""

    @property
    def skill(self) -> np.ndarray:
        """(n_cars,) skills, writable per car."""
        return self.driver.skill

    def place(self, car_ids: np.ndarray, s_m: np.ndarray, speed_share: float = 1.0) -> None:
        """Put cars on the racing line at ``s_m``, rolling at ``speed_share`` x their skill's speed there."""
        car_ids = np.asarray(car_ids, dtype=np.int64)
        place_on_line(self.world, self.line, self.profile, car_ids, s_m, speed_share * self.skill[car_ids])

    def advance(
        self,
        world_steps: int = 1,
        held_ids: np.ndarray | None = None,
        held_steer_rad: np.ndarray | None = None,
        held_omega: np.ndarray | None = None,
    ) -> StepEvents:
        """``world_steps`` world steps, the AI acting at each for every car except ``held_ids``, whose commands
        are held. The state's contact flags then cover the whole advance (a touch in any step counts), as a
        caller stepping at the coarser rate would see them."""
        world = self.world
        n = world.n_cars
        if held_ids is not None and len(held_ids) == n and self.disruptor is None:
            # Nobody for the AI to drive: one kernel call for the whole advance.
            steer, omega = np.empty(n), np.empty(n)
            steer[held_ids], omega[held_ids] = held_steer_rad, held_omega
            return world.step(steer, omega, world_steps)
        lap_completed, lap_time_s = np.zeros(n, dtype=bool), np.full(n, np.nan)
        wall_any, car_any = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        omega_sum = np.zeros(n)
        for _ in range(world_steps):
            steer, omega = self.driver.act(world.state)
            if self.disruptor is not None:
                steer, omega = self.disruptor(steer, omega, world.model.config.control_dt_s)
            if held_ids is not None:
                steer[held_ids], omega[held_ids] = held_steer_rad, held_omega
            omega_sum += omega
            events = world.step(steer, omega)
            wall_any |= world.state.wall_contact
            car_any |= world.state.car_contact
            lap_completed |= events.lap_completed
            lap_time_s = np.where(events.lap_completed, events.lap_time_s, lap_time_s)
        world.state = world.state._replace(wall_contact=wall_any, car_contact=car_any)
        self.last_steer_rad, self.mean_omega = steer, omega_sum / world_steps
        return StepEvents(lap_completed, lap_time_s)


def place_on_line(world: World, line, profile, car_ids: np.ndarray, s_m: np.ndarray, speed_share) -> None:
    """Put cars ``car_ids`` on the racing line at ``s_m``, rolling at ``speed_share`` (per car or one) x the limit
    speed profile there."""
    s = np.asarray(s_m, dtype=np.float64)
    speed = np.asarray(speed_share) * profile.speed_at(line.line_s_at(s))
    world.reset(s_m=s, lateral_m=line.lateral_at(s), speed_mps=speed, car_ids=np.asarray(car_ids, dtype=np.int64))
