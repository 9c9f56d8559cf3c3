"""Calibration of the pad's effective stiffness K and damping D to the paper's experiments.

The six experimental values of Tables 5 and 6 (peak pad deformation and collision acceleration of
conditions 1-3) are fitted by least squares on this model: each residual is the model's value
minus the experiment's, in % of the experiment. The model's value is the first contact of the
ideal-microgravity landing (:mod:`microg_env.sim.reference`), simulated in MuJoCo from the touchdown at
the speed of the ideal free fall; the rig under the PID lands like it to 0.03 % in deformation and
0.3 % in acceleration (docs/paper.md), and ``microg reproduce`` checks the fit on the full rig.

The pad stays the linear spring-damper of Section 2; a Hunt-Crossley exponent is not fitted: the
experiments' own ratios contradict any single power law (see the reproduction report), and
MuJoCo's soft contact is linear in penetration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from importlib import resources

import mujoco
import numpy as np
from mujoco import minimize

from microg_env.files import parse_toml
from microg_env.paper.tables import PUBLISHED, experiment_relative_error_pct
from microg_env.params import PAD_NAMES, PadParams, RigParams
from microg_env.scenarios import CONDITIONS, Scenario
from microg_env.sim.contact import damping_ratio
from microg_env.sim.model import build_pad_test, pad_contact_solref

#: Damping ratio the search may not cross (Section 2 needs an under-damped pad).
_MAX_DAMPING_RATIO = 0.95
#: The fit's finite-difference step on log K and log damping ratio: a landing's peaks are read at
#: physics steps, so the residuals are smooth only at steps far above the solver's default 1.5e-8.
_FIT_STEP = 1e-4
#: The factor the solver's regulariser grows by when a step is refused (mujoco.minimize's default is
#: 10^0.1). At the optimum the residuals' roughness at the physics step refuses every step: at 10^0.1
#: the solver tried some 140 regularisers before it stopped (161 evaluations of the six residuals in
#: a fit), at 10 it tries 14 (35 in a fit), and K and D agree to 2e-6.
_REGULARISER_FACTOR = 10.0


class LandingModel:
    """The first contact of a scenario's ideal landing, for any pad (K, D)."""

    def __init__(self, scenario: Scenario, params: RigParams | None = None) -> None:
        params = RigParams() if params is None else params
        placed = scenario.stages_kg[-1]
        self.mass_kg = params.lander.mass_kg + placed
        self.params = params
        self.pad_test = build_pad_test(params, field_m_s2=placed * params.gravity_m_s2 / self.mass_kg)
        model = self.pad_test.model
        model.body_mass[model.body("lander").id] = self.mass_kg
        self.impact_speed_m_s = scenario.impact_speed_m_s(params.lander.mass_kg, params.gravity_m_s2)
        self._pad = model.geom("pad").id
        self._data = mujoco.MjData(model)
        self._force = int(model.sensor_adr[model.sensor("pad_force").id])

    def land(self, stiffness_n_per_m: float, damping_n_s_per_m: float) -> tuple[float, float]:
        """Peak deformation (m) and peak upward acceleration (m/s^2) of the first contact."""
        model, data, pad = self.pad_test.model, self._data, self.params.pad
        model.geom_solref[self._pad] = pad_contact_solref(
            stiffness_n_per_m, damping_n_s_per_m, self.mass_kg, self.pad_test.pad_contacts, pad.impedance
        )[0]
        mujoco.mj_resetData(model, data)
        data.qvel[0] = -self.impact_speed_m_s
        deepest, peak, pushed = 0.0, -math.inf, False
        limit = 4.0 * math.pi * math.sqrt(self.mass_kg / stiffness_n_per_m)  # two undamped periods
        while data.time < limit:
            mujoco.mj_step(model, data)
            deepest = min(deepest, data.qpos[0])
            if data.sensordata[self._force] > 0.0:
                pushed = True
                peak = max(peak, data.qacc[0])
            elif pushed:
                break
        return -deepest, peak


@dataclass(frozen=True)
class Calibration:
    """Fitted pad and its residuals (model - target, % of target) per condition."""

    stiffness_n_per_m: float
    damping_n_s_per_m: float
    max_deformation_pct: tuple[float, float, float]
    collision_accel_pct: tuple[float, float, float]
    iterations: int

    @property
    def rms_residual_pct(self) -> float:
        values = np.array(self.max_deformation_pct + self.collision_accel_pct)
        return float(np.sqrt(np.mean(values**2)))

    def as_dict(self) -> dict:
        """What ``microg calibrate --json`` prints."""
        return {
            "stiffness_n_per_m": self.stiffness_n_per_m,
            "damping_n_s_per_m": self.damping_n_s_per_m,
            "residuals": {
                "max_deformation_pct": list(self.max_deformation_pct),
                "collision_accel_pct": list(self.collision_accel_pct),
            },
        }


def paper_targets(source: str) -> tuple[np.ndarray, np.ndarray]:
    """Peak deformation (mm) and collision acceleration (mm/s^2) of conditions 1-3 in the paper:
    its experiment (Tables 5 and 6 "actual") or its simulation (Tables 5 and 6 "theoretical")."""
    if source == "experiment":
        pairs = [(c.measured_max_deformation_mm, c.measured_collision_accel_mm_s2) for c in PUBLISHED.values()]
    elif source == "simulation":
        pairs = [(c.simulated_max_deformation_mm, c.simulated_collision_accel_mm_s2) for c in PUBLISHED.values()]
    else:
        raise ValueError(f"source must be 'experiment' or 'simulation', got {source!r}")
    deformation, acceleration = zip(*pairs, strict=True)
    return np.array(deformation), np.array(acceleration)


class _Residuals:
    """The six residuals of a pad, in % of the targets, from the three conditions' landing models."""

    def __init__(self, params: RigParams, source: str) -> None:
        self.models = [LandingModel(CONDITIONS[n], params) for n in (1, 2, 3)]
        self.deformation_mm, self.acceleration_mm_s2 = paper_targets(source)

    def __call__(self, stiffness: float, damping: float) -> np.ndarray:
        landings = np.array([model.land(stiffness, damping) for model in self.models]) * 1e3
        return np.concatenate(
            [
                experiment_relative_error_pct(landings[:, 0], self.deformation_mm),
                experiment_relative_error_pct(landings[:, 1], self.acceleration_mm_s2),
            ]
        )


def calibrate(params: RigParams | None = None, source: str = "experiment", max_iterations: int = 50) -> Calibration:
    """Least-squares K and D (``mujoco.minimize.least_squares`` from Table 1's values).

    The unknowns are log K and the log of the heaviest landing's damping ratio, bounded below
    :data:`_MAX_DAMPING_RATIO` (Section 2 needs an under-damped pad), so the bound is a box.
    ``source`` "experiment" fits the paper's measurements; "simulation" finds the pad that makes
    this model land as the paper's own simulation did.
    """
    params = RigParams() if params is None else params
    residuals = _Residuals(params, source)
    heaviest = max(model.mass_kg for model in residuals.models)

    def pad(z: np.ndarray) -> tuple[float, float]:
        stiffness = math.exp(z[0])
        return stiffness, 2.0 * math.exp(z[1]) * math.sqrt(stiffness * heaviest)  # Eq. 2 solved for D

    def residual(z: np.ndarray) -> np.ndarray:  # z: (2, points)
        return np.column_stack([residuals(*pad(point)) for point in z.T])

    start = params.pad.stiffness_n_per_m, params.pad.damping_n_s_per_m
    z0 = np.log([start[0], damping_ratio(heaviest, *start)])
    bounds = (np.array([math.log(1.0), math.log(1e-3)]), np.array([math.log(1e7), math.log(_MAX_DAMPING_RATIO)]))
    z, trace = minimize.least_squares(
        z0,
        residual,
        bounds=bounds,
        eps=_FIT_STEP,
        mu_factor=_REGULARISER_FACTOR,
        max_iter=max_iterations,
        verbose=minimize.Verbosity.SILENT,
    )
    stiffness, damping = pad(z)
    r = residuals(stiffness, damping)
    return Calibration(stiffness, damping, tuple(map(float, r[:3])), tuple(map(float, r[3:])), len(trace) - 1)


def stored_pads() -> dict[str, dict]:
    """The fitted pads of config/pads.toml, each with its K, D and provenance."""
    text = resources.files("microg_env").joinpath("config", "pads.toml").read_text(encoding="utf-8")
    return parse_toml(text)


def stored_calibration(name: str) -> Calibration:
    """The fit stored under ``name`` ("calibrated" or "paper-simulation") in config/pads.toml."""
    if name not in PAD_NAMES[1:]:
        raise ValueError(f"stored pad must be one of {', '.join(PAD_NAMES[1:])}, got {name!r}")
    stored = stored_pads()[name]
    return Calibration(
        stored["stiffness_n_per_m"],
        stored["damping_n_s_per_m"],
        tuple(stored["max_deformation_pct"]),
        tuple(stored["collision_accel_pct"]),
        stored["iterations"],
    )


def pad_params(name: str) -> PadParams:
    """Table 1's pad ("paper"), or a fitted pad stored in config/pads.toml by ``microg calibrate``:
    "calibrated" (fitted to the paper's experiments) or "paper-simulation" (the pad with which this
    model lands as the paper's simulation did)."""
    if name not in PAD_NAMES:
        raise ValueError(f"pad must be one of {', '.join(PAD_NAMES)}, got {name!r}")
    table1 = PadParams()
    if name == "paper":
        return table1
    fit = stored_calibration(name)
    return replace(table1, stiffness_n_per_m=fit.stiffness_n_per_m, damping_n_s_per_m=fit.damping_n_s_per_m)


def with_pad(params: RigParams, name: str) -> RigParams:
    """``params`` with the named pad (see :func:`pad_params`)."""
    pad = pad_params(name)
    return replace(
        params,
        pad=replace(params.pad, stiffness_n_per_m=pad.stiffness_n_per_m, damping_n_s_per_m=pad.damping_n_s_per_m),
    )
