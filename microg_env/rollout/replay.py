"""A rig log from a run, and a log's commands run on the model (:mod:`microg_env.logs`' schema).

:class:`LogRecorder` writes what the model's sensors read and the commands its controller sent, as
a real rig's computer logs them. :func:`replay` runs a log's commands on a model rig and reads the
model's ruler and encoder beside the log's.

The lander on the QZS is unstable open loop where Eq. 17's residual stiffness is negative (the
literal reading: e-folding in about 0.13 s for the paper's rig), so a replay of a whole test would
leave the log within a few seconds whatever the model. The replay therefore runs in windows. At
each window's start the lander's x is set to the log's (the ruler less the model's zero offset),
and its rate to the lander's speed (a parabola fitted to its height, encoder plus ruler) less the
model's support's. The drive, which is stable, runs on from the log's start. What the start state
explains of a window's ruler residual (its sensitivities, from two copies of the replay with the
state shifted) is removed; what is left measures the lander's side (QZS, friction, pad, the
ruler's zero), and the encoder's residual the drive's (speed loop, torque filter, cogging).
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding

from microg_env import validate
from microg_env.envs.core import LandingCore
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.interface import MAX_SPEED_M_S, OBSERVATION_INDEX, SCALES, SENSOR_SETS, speed_commands_m_s
from microg_env.logs import DEFAULT_WINDOW_S, OPTIONAL_COLUMNS, RigLog
from microg_env.params import PHYSICS_STEP_S, RigParams, with_overrides
from microg_env.task import TaskSettings
from microg_env.validate import FieldError

#: The shifts of a window's start state whose effects are its sensitivities to it: within the
#: guide's 2 um of pre-sliding and far above float rounding.
X_SHIFT_M, RATE_SHIFT_M_S = 1e-8, 1e-6
#: The time on each side of a window's start that the lander's speed is fitted over, s.
RATE_FIT_HALF_WIDTH_S = 0.02
#: Fewest rows a window may hold: the two sensitivities of its start state are removed from each.
MIN_WINDOW_ROWS = 10
#: The log's columns and the observation entries the model's sensors read them into.
READINGS = {
    "ruler_m": "x",
    "encoder_m": "support_position",
    "accelerometer_m_s2": "lander_accel",
    "pad_force_n": "pad_force",
}


class LogRecorder:
    """An ``on_step(env, info)`` callback of :func:`~microg_env.rollout.episode.run_episode`: the
    sensors' readings after the reset and each step, and each step's command; :meth:`log` is the
    episode as a rig log (the accelerometer and pad force where the rig's sensor set reads them)."""

    def __init__(self) -> None:
        self._times: list[float] = []
        self._readings: list[np.ndarray] = []
        self._commands: list[float] = []
        self._env: MicroGravityLandingEnv | None = None
        self._sensor_set = "extended"
        self._force = OBSERVATION_INDEX["pad_force"]

    def __call__(self, env: gym.Env, info: dict) -> None:
        core = env.unwrapped.core
        self._sensor_set = str(info["sensor_set"])
        if self._readings:  # the step's action: the speed reference sent
            limit = env.unwrapped.settings.speed_limit_m_s
            self._commands.append(float(speed_commands_m_s(core.previous_action[:1], limit)[0]))
        # Ruler, encoder and accelerometer at full precision (the observation's float32 is 6 nm of the
        # encoder); the pad force as the observation holds it (float32: 6 uN of 100 N).
        force = float(core.observation[0, self._force]) * SCALES[self._force]
        self._readings.append(np.array([*core.last_readings[:, 0], core.accelerometer[0], force]))
        self._times.append(float(info["time_s"]))
        self._env = env.unwrapped

    def log(self) -> RigLog:
        """The episode's log: a row for each step (its readings and the command they gave)."""
        if self._env is None or not self._commands:
            raise ValueError("the recorder has seen no step")
        rows = len(self._commands)
        readings = np.array(self._readings[:rows])
        columns = {"time_s": np.array(self._times[:rows]), "command_m_s": np.array(self._commands)}
        kept = [name for name in READINGS if name not in OPTIONAL_COLUMNS or self._reads(name)]
        for name in kept:
            columns[name] = readings[:, list(READINGS).index(name)]
        scenario = self._env.active_scenario
        return RigLog(columns, self._env.core.episodes[0].height_m, scenario.loads)  # the start's, drawn or not

    def _reads(self, name: str) -> bool:
        """Whether the episode's sensor set has the sensor of column ``name``."""
        return READINGS[name] not in SENSOR_SETS[self._sensor_set]


@dataclass(frozen=True)
class Replay:
    """The model's ruler and encoder readings, without noise or quantisation, one per row of the
    ``log`` (the rows a replay that ended early reached; ``ended``: why it ended, or None).
    ``ruler_m`` has three rows: the replay, and the replays with each window's x and then its rate
    set :data:`X_SHIFT_M` and :data:`RATE_SHIFT_M_S` higher, whose differences are the window's
    sensitivities to the lander's state set at its start."""

    log: RigLog
    ruler_m: np.ndarray
    encoder_m: np.ndarray
    window_rows: int
    ended: str | None = None

    def residuals(self) -> dict[str, np.ndarray]:
        """Model minus log, per channel, over the rows replayed; the ruler's with the part that the
        window's start state explains removed (its least-squares projection on the sensitivities)."""
        n = self.encoder_m.size
        ruler = self.ruler_m[0] - self.log.columns["ruler_m"][:n]
        sensitivities = np.stack(
            [(self.ruler_m[1] - self.ruler_m[0]) / X_SHIFT_M, (self.ruler_m[2] - self.ruler_m[0]) / RATE_SHIFT_M_S]
        )
        for start in range(0, n, self.window_rows):
            part, basis = ruler[start : start + self.window_rows], sensitivities[:, start : start + self.window_rows]
            if part.size > basis.shape[0]:
                part -= basis.T @ np.linalg.lstsq(basis.T, part, rcond=None)[0]
        return {"ruler_m": ruler, "encoder_m": self.encoder_m - self.log.columns["encoder_m"][:n]}

    def rms(self) -> dict[str, float]:
        return rms(self.residuals())


def rms(residuals: dict[str, np.ndarray]) -> dict[str, float]:
    """The root mean square of each channel's residuals."""
    return {name: float(np.sqrt(np.mean(r**2))) for name, r in residuals.items()}


def replay(
    log: RigLog,
    params: RigParams | None = None,
    window_s: float = DEFAULT_WINDOW_S,
    physics_step_s: float = PHYSICS_STEP_S,
    seed: int = 0,
) -> Replay:
    """Run ``log``'s commands on the rig ``params`` (default the paper's) in windows of
    ``window_s`` (see the module's docstring). The balancer's drift, which a log does not give, is
    off; ``seed`` draws the rest of the episode (the sensors' noise, which the replay does not read)."""
    period = log.control_period_s
    window = round(validate.positive("window_s", window_s, "s") / period)
    if window < MIN_WINDOW_ROWS:
        raise FieldError(
            f"window_s {window_s!r} holds {window} rows of the log; give at least {MIN_WINDOW_ROWS} "
            f"({MIN_WINDOW_ROWS * period:g} s): the start state's two sensitivities are removed from each",
            "window_s",
        )
    commands = log.columns["command_m_s"]
    fast = np.flatnonzero(np.abs(commands) > MAX_SPEED_M_S)
    if fast.size:
        raise ValueError(
            f"command_m_s {float(commands[fast[0]])!r} in row {fast[0] + 1} is beyond the drive's {MAX_SPEED_M_S} m/s"
        )
    rig = RigParams() if params is None else params  # its drift drawn from no log: off
    rig = with_overrides(rig, {"drift.max_temperature_rate_k_per_s": 0.0})
    settings = TaskSettings(scenario=log.scenario(), control_period_s=period, physics_step_s=physics_step_s, params=rig)
    # The replay and its two shifted copies, on one thread: a second one spins through each call's
    # single physics step (identify's fits: the same wall time, 55 % more CPU time).
    core = LandingCore(3, settings, batched=True, nthread=1)
    return _replayed(core, log, window, [seeding.np_random(seed)[0] for _ in range(3)])


def _replayed(core: LandingCore, log: RigLog, window: int, rngs: list) -> Replay:
    every = np.arange(3)
    core.reset(every, rngs)
    physics, rig = core.physics, core.rig
    offset = core.base_params.sensors.ruler_zero_offset_m
    ruler, commands = log.columns["ruler_m"], log.columns["command_m_s"]
    height = log.columns["encoder_m"] + ruler  # the lander's, smooth where x is not
    n = log.rows
    sim_ruler, sim_encoder = np.empty((3, n)), np.empty(n)
    shift_x, shift_rate = np.array([0.0, X_SHIFT_M, 0.0]), np.array([0.0, 0.0, RATE_SHIFT_M_S])
    for k in range(n):
        if k % window == 0:  # the lander's state from the log; the support's the model's own
            _copy_first_rig(core)
            physics.qpos[:, rig.qzs_qpos] = ruler[k] - offset + shift_x
            lander = _rate(height, k, log.control_period_s)
            physics.qvel[:, rig.qzs_dof] = lander - physics.qvel[:, rig.screw_dof] + shift_rate
            physics.forward(every)
        sim_ruler[:, k] = physics.qpos[:, rig.qzs_qpos] + offset
        sim_encoder[k] = physics.qpos[0, rig.motor_qpos]  # what the encoder reads, unquantised
        if k < n - 1:
            _, codes, _, _ = core.step(every, np.full(3, commands[k] / MAX_SPEED_M_S), rngs)
            if codes.any():  # the model left the log (a stroke's end, the pad's floor)
                reason = str(core.info(every, codes)["termination_reason"][np.flatnonzero(codes)[0]])
                return Replay(log, sim_ruler[:, : k + 1], sim_encoder[: k + 1], window, reason)
    return Replay(log, sim_ruler, sim_encoder, window)


def _copy_first_rig(core: LandingCore) -> None:
    """The shifted copies' state made the replay's own, so each window's sensitivities are its own."""
    physics = core.physics
    for name in ("qpos", "qvel", "act", "ctrl", "qfrc_applied"):
        field = getattr(physics, name)
        field[1:] = field[0]
    for name in ("position_ref", "pending_command", "command", "previous_action", "motor_speed"):
        field = getattr(core, name)
        field[1:] = field[0]


def _rate(height: np.ndarray, k: int, period: float) -> float:
    """The lander's speed at row ``k``: the slope at ``k`` of a least-squares parabola through its
    height within :data:`RATE_FIT_HALF_WIDTH_S` of it (less at the log's ends)."""
    half = max(2, round(RATE_FIT_HALF_WIDTH_S / period))
    lo, hi = max(0, k - half), min(len(height), k + half + 1)
    t = (np.arange(lo, hi) - k) * period
    return float(np.polyfit(t, height[lo:hi] - height[k], 2)[1])
