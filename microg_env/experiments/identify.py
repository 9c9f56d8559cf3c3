"""Rig parameters identified from a rig's logs: least squares on the replay's residuals.

The residuals are :func:`~microg_env.rollout.replay.replay`'s, model minus log, of the ruler and
the encoder, each divided by its reading's standard deviation (noise and quantisation, from the
rig's sensor parameters), over every log. ``mujoco.minimize.least_squares`` fits the chosen
parameters, each in units of its :data:`FIT_SCALES` entry, within its range
(:data:`~microg_env.params.RANGES`). The 95 % intervals are the linearised ones at the optimum:
1.96 sqrt(diag(s^2 (J^T J)^-1)), with J the residuals' Jacobian by central differences and s^2
the residuals' mean square (so a model that fits worse than the sensors' noise widens them).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from mujoco import minimize

from microg_env.logs import DEFAULT_WINDOW_S, RigLog
from microg_env.params import PHYSICS_STEP_S, RANGES, RigParams, parameter_paths, with_overrides
from microg_env.rollout.replay import Replay, replay, rms
from microg_env.workers import process_pool

#: The parameters ``identify`` may fit, each with the scale it is fitted in (a unit of the solver).
FIT_SCALES = {
    "servo.speed_loop_gain_hz": 10.0,
    "servo.torque_filter_s": 1e-4,
    "servo.cogging_torque_n_m": 0.05,
    "qzs.residual_stiffness_n_per_m": 5000.0,
    "sensors.ruler_zero_offset_m": 1e-6,
    "pad.stiffness_n_per_m": 500.0,
    "pad.damping_n_s_per_m": 20.0,
}
#: Those a log identifies only if the foot touches the pad in it.
LANDING_PARAMETERS = ("pad.stiffness_n_per_m", "pad.damping_n_s_per_m")
#: Finite-difference step of the Jacobian, in fit units.
STEP = 1e-3
#: The factor the solver's regulariser grows by when a step is refused (mujoco.minimize's default is
#: 10^0.1). Near the optimum the replay's residuals are rough at the physics step and refuse step
#: after step, each a replay of every log: a fit of two parameters on 1 s took 144 replays at 10^0.1,
#: 37 at 10. But at 10 a fit of five on 1.8 s of free fall stopped in a wrong valley of the residual
#: stiffness and the ruler's zero (their product is a constant force on the lander, which a free
#: fall measures best), 43 % and 59 % off; at 10^0.5 it found both within 1 % (benchmarks/identifiability.py).
REGULARISER_FACTOR = 10**0.5
#: The residual, in standard deviations, of a row a replay did not reach (it left the log).
LEFT_LOG = 1e3
#: z for a 95 % interval.
Z95 = 1.959964


@dataclass(frozen=True)
class Identification:
    """The fitted ``values`` and their 95 % ``half_widths``, by dotted path; the ``start``; each
    channel's residual RMS at the optimum (m) beside its reading's standard deviation (``noise``);
    the solver's iterations; the logs fitted."""

    values: dict[str, float]
    half_widths: dict[str, float]
    start: dict[str, float]
    rms: dict[str, float]
    noise: dict[str, float]
    iterations: int
    logs: tuple[str, ...]


def reading_noise(params: RigParams) -> dict[str, float]:
    """The standard deviation of a ruler and an encoder reading, m: noise and quantisation."""
    sensors, screw = params.sensors, params.screw
    encoder_step = screw.lead_m / screw.belt_ratio / sensors.encoder_counts_per_rev
    return {
        "ruler_m": math.hypot(sensors.ruler_noise_m, sensors.ruler_resolution_m / math.sqrt(12.0)),
        "encoder_m": encoder_step / math.sqrt(12.0),
    }


def touches_pad(log: RigLog, params: RigParams) -> bool:
    """Whether the foot reaches the pad in ``log``: its height, encoder plus ruler less the ruler's
    zero, at or below the pad's surface."""
    height = log.columns["encoder_m"] + log.columns["ruler_m"] - params.sensors.ruler_zero_offset_m
    return bool(height.min() <= 0.0)


def default_fit(logs: Sequence[RigLog], params: RigParams) -> tuple[str, ...]:
    """What :func:`identify` fits unless told: every :data:`FIT_SCALES` parameter, the pad's only
    where a log lands."""
    lands = any(touches_pad(log, params) for log in logs)
    return tuple(name for name in FIT_SCALES if lands or name not in LANDING_PARAMETERS)


@dataclass(frozen=True)
class _Problem:
    """The residual of :func:`identify`'s parameters ``fit`` at z, their fit units about ``origin``
    (picklable, for a process pool's workers)."""

    logs: tuple[RigLog, ...]
    params: RigParams
    fit: tuple[str, ...]
    origin: np.ndarray
    scales: np.ndarray
    window_s: float
    physics_step_s: float

    def values(self, z: np.ndarray) -> dict[str, float]:
        return {name: float(v) for name, v in zip(self.fit, self.origin + self.scales * z, strict=True)}

    def replays(self, rig: RigParams) -> list[Replay]:
        return [replay(log, rig, self.window_s, self.physics_step_s) for log in self.logs]

    def __call__(self, z: np.ndarray) -> np.ndarray:
        noise = reading_noise(self.params)
        try:
            rig = with_overrides(self.params, self.values(z))
        except ValueError:  # a combination the rig refuses (a negative stiffness's sign crossed)
            return np.full(sum(2 * log.rows for log in self.logs), LEFT_LOG)
        parts = [
            np.concatenate([r / noise[name], np.full(log.rows - r.size, LEFT_LOG)])
            for log, run in zip(self.logs, self.replays(rig), strict=True)
            for name, r in run.residuals().items()
        ]
        return np.concatenate(parts)


def identify(
    logs: Sequence[RigLog],
    params: RigParams | None = None,
    fit: Sequence[str] | None = None,
    window_s: float = DEFAULT_WINDOW_S,
    physics_step_s: float = PHYSICS_STEP_S,
    max_iterations: int = 50,
    workers: int = 1,
    on_point: Callable[[], None] | None = None,
) -> Identification:
    """The parameters ``fit`` (default :func:`default_fit`) that make the model replay ``logs``
    best, from the rig ``params`` (default the paper's), which gives every other parameter; the
    points of a Jacobian on ``workers`` processes; ``on_point()`` after each point's replays. A
    parameter the logs do not move the residuals of has an infinite interval. A log the model
    leaves at the optimum (a stroke's end) is refused, named."""
    params = RigParams() if params is None else params
    if not logs:
        raise ValueError("give at least one log")
    fit = default_fit(logs, params) if fit is None else tuple(fit)
    unknown = [name for name in fit if name not in FIT_SCALES]
    if unknown or not fit or len(set(fit)) < len(fit):
        raise ValueError(f"fit: give distinct parameters of {', '.join(FIT_SCALES)}, got {', '.join(fit) or 'none'}")
    start = {name: float(parameter_paths(params)[name]) for name in fit}
    scales = np.array([FIT_SCALES[name] for name in fit])
    origin = np.array([start[name] for name in fit])
    low, high = (np.array([_range(name)[i] for name in fit]) for i in (0, 1))
    low, high = (low - origin) / scales, (high - origin) / scales
    problem = _Problem(tuple(logs), params, fit, origin, scales, window_s, physics_step_s)
    with contextlib.ExitStack() as stack:
        pool = stack.enter_context(process_pool(workers)) if workers > 1 else None

        def points(z: np.ndarray) -> np.ndarray:  # z: (parameters, points)
            columns = pool.map(problem, list(z.T)) if pool is not None else map(problem, z.T)
            out = []
            for column in columns:
                out.append(column)
                if on_point is not None:
                    on_point()
            return np.column_stack(out)

        z, trace = minimize.least_squares(
            np.zeros(len(fit)),
            points,
            bounds=(low, high),
            eps=STEP,
            mu_factor=REGULARISER_FACTOR,
            max_iter=max_iterations,
            verbose=minimize.Verbosity.SILENT,
        )
        # The Jacobian at the optimum by differences within the bounds (one-sided at one).
        ahead, behind = np.minimum(z + STEP, high) - z, z - np.maximum(z - STEP, low)
        shifted = [z + np.eye(len(fit))[i] * ahead[i] for i in range(len(fit))]
        shifted += [z - np.eye(len(fit))[i] * behind[i] for i in range(len(fit))]
        around = points(np.column_stack([z, *shifted]))
    n = len(fit)
    r = around[:, 0]
    jacobian = (around[:, 1 : n + 1] - around[:, n + 1 :]) / (ahead + behind)
    seen = np.linalg.norm(jacobian, axis=0) > 0.0
    s2 = float(r @ r) / max(1, r.size - n)
    half = np.full(n, math.inf)
    if seen.any():
        covariance = s2 * np.linalg.pinv(jacobian[:, seen].T @ jacobian[:, seen])
        half[seen] = Z95 * np.sqrt(np.clip(np.diag(covariance), 0.0, None)) * scales[seen]
    values = problem.values(z)
    replays = problem.replays(with_overrides(params, values))
    _check_left(replays, logs)
    noise = reading_noise(params)
    sets = [run.residuals() for run in replays]  # each replay's, once
    fit_rms = rms({name: np.concatenate([residuals[name] for residuals in sets]) for name in noise})
    return Identification(
        values,
        {name: float(h) for name, h in zip(fit, half, strict=True)},
        start,
        fit_rms,
        noise,
        len(trace) - 1,
        tuple(log.source for log in logs),
    )


def _check_left(replays: Sequence[Replay], logs: Sequence[RigLog]) -> None:
    """A ValueError naming the first log whose replay ended early, and why."""
    for run, log in zip(replays, logs, strict=True):
        if run.ended is not None:
            raise ValueError(
                f"log {log.source!r}: the model leaves it at row {run.encoder_m.size} of {log.rows} "
                f"({run.ended}): it is not this rig's, or its start height or loads are not the test's"
            )


def _range(name: str) -> tuple[float, float]:
    """The range of the parameter at dotted path ``name`` (:data:`RANGES`)."""
    part, _, field = name.partition(".")
    kind = type(getattr(RigParams(), part)).__name__
    if name == "qzs.residual_stiffness_n_per_m":  # signed: |k| in [1, 1e8] (QZSParams)
        return -1e8, 1e8
    low, high, _ = RANGES[f"{kind}.{field}"]
    return low, high
