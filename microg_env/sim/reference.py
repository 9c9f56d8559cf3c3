"""The ideal-microgravity reference: what the rig is meant to reproduce.

The same lander and pad, no rig: the lander with the weights placed so far (mass M + m) falls in
a uniform field m g / (M + m) from the scenario's descent height, the field and the mass changing
when the scenario places a weight, exactly as on an ideal rig. Sampled at the control period, it
is the yardstick of :func:`microg_env.analysis.metrics.compute_metrics`.

Between contacts the lander flies freely, and MuJoCo's step reduces to ``v += h a``, ``z += h v``
with a constant ``a``: those steps (most of a landing's) are taken by :func:`_free_flight`, the same
arithmetic bit for bit without the rest of MuJoCo's pipeline (tests/sim/test_reference.py), and
MuJoCo steps again :data:`CLEARANCE_M` above the pad, or before a weight is placed.

Many runs share one reference (a PID's gains, the QZS, the balancer, the drive and the sensors do
not enter it; a shorter run's is a prefix of a longer one's): the last few are kept, by what enters
them (:func:`reference_key`), and a shorter one is cut from a longer one, bit for bit the same.
"""

from __future__ import annotations

import math
from dataclasses import replace

import mujoco
import numpy as np

from microg_env.compiled import jit
from microg_env.params import RigParams
from microg_env.scenarios import Scenario
from microg_env.sim.model import build_pad_test, pad_contact_solref
from microg_env.trajectory import CHANNELS, Trajectory

#: References kept for reuse (each 30 s one is ~2 MB).
KEPT = 8
#: The foot's lowest height in a free-flight step (m): MuJoCo's pad contact begins at 0 (no margin).
CLEARANCE_M = 1e-3
_kept: dict[tuple, Trajectory] = {}


def reference_key(scenario: Scenario, params: RigParams, control_period_s: float, physics_step_s: float) -> tuple:
    """What a reference depends on: the schedule (not its duration, which only cuts it), the parts of
    ``params`` the lander-and-pad model (:func:`~microg_env.sim.model.build_pad_test`) is built from,
    and the steps."""
    parts = (params.lander, params.pad, params.qzs.stroke_m, params.screw, params.gravity_m_s2)
    return (replace(scenario, duration_s=Scenario.duration_s), *parts, control_period_s, physics_step_s)


def simulate_reference(
    scenario: Scenario,
    params: RigParams,
    control_period_s: float,
    physics_step_s: float,
    duration_s: float | None = None,
) -> Trajectory:
    """The ideal landing of ``scenario`` with the lander, pad and gravity of ``params`` for
    ``duration_s`` (default: the scenario's), sampled at ``control_period_s``: simulated, or cut
    from a longer one kept from an earlier call."""
    duration_s = scenario.duration_s if duration_s is None else duration_s
    steps = round(duration_s / control_period_s)
    key = reference_key(scenario, params, control_period_s, physics_step_s)
    kept = _kept.get(key)
    if kept is None or len(kept) < steps + 1:
        kept = _simulate(scenario, params, control_period_s, physics_step_s, steps)
        _keep(key, kept)
    return cut_reference(kept, steps + 1, scenario)


def _keep(key: tuple, trajectory: Trajectory) -> None:
    """Keep ``trajectory`` as the reference of ``key`` (:func:`reference_key`) for
    :func:`simulate_reference` to cut."""
    _kept.pop(key, None)
    _kept[key] = trajectory
    while len(_kept) > KEPT:
        del _kept[next(iter(_kept))]


def cut_reference(trajectory: Trajectory, length: int, scenario: Scenario) -> Trajectory:
    """The first ``length`` samples of ``trajectory``, as new arrays, the landing of ``scenario``
    (the schedule it was simulated for, perhaps of another length)."""
    arrays = {name: getattr(trajectory, name)[:length].copy() for name in CHANNELS}
    return replace(trajectory, scenario=scenario, **arrays)


def _simulate(
    scenario: Scenario, params: RigParams, control_period_s: float, physics_step_s: float, steps: int
) -> Trajectory:
    frame_skip = round(control_period_s / physics_step_s)
    pad_test = build_pad_test(params, physics_step_s=physics_step_s)
    model = pad_test.model
    data = mujoco.MjData(model)
    lander, pad_geom = model.body("lander").id, model.geom("pad").id
    force_adr = int(model.sensor_adr[model.sensor("pad_force").id])
    g, mass, pad = params.gravity_m_s2, params.lander.mass_kg, params.pad

    def place(count: int) -> float:
        placed = sum(load.mass_kg for load in scenario.loads[:count])
        total = mass + placed
        model.body_mass[lander] = total
        model.opt.gravity[2] = -placed * g / total
        model.geom_solref[pad_geom] = pad_contact_solref(
            pad.stiffness_n_per_m, pad.damping_n_s_per_m, total, pad_test.pad_contacts, pad.impedance
        )[0]
        return placed

    data.qpos[0] = scenario.descent_height_m
    placed = scenario.loads_due(scenario.descent_height_m, 0)
    placed_kg = place(placed)
    mujoco.mj_forward(model, data)
    time, height, velocity, accel, force, load, stage = (np.zeros(steps + 1) for _ in range(7))
    samples = (time, height, velocity, accel)

    def record(k: int) -> None:
        time[k], height[k], velocity[k], accel[k] = _state(data)
        force[k], load[k], stage[k] = data.sensordata[force_adr], placed_kg, placed - 1

    record(0)
    flies = _flies_as_mujoco(model, data, frame_skip)
    field_known = True  # data.qacc is the acceleration in this stage's field, if the last step was free
    k = 1
    while k <= steps:
        if flies and field_known and data.ncon == 0:
            flown = _free_flight(
                *samples, k, steps, frame_skip, model.opt.timestep, _floor(scenario, placed), *_state(data)
            )
            if flown:
                force[k : k + flown], load[k : k + flown], stage[k : k + flown] = 0.0, placed_kg, placed - 1
                k += flown
                data.time, data.qpos[0], data.qvel[0] = time[k - 1], height[k - 1], velocity[k - 1]
                if k > steps:
                    break
        mujoco.mj_step(model, data, nstep=frame_skip)
        field_known = True
        if placed < len(scenario.loads):
            due = scenario.loads_due(float(data.qpos[0]), placed)
            if due != placed:
                placed, placed_kg = due, place(due)
                field_known = False  # the field changed after MuJoCo's last step
        record(k)
        k += 1
    return Trajectory.from_channels(
        scenario,
        g,
        mass,
        time_s=time,
        foot_height_m=height,
        lander_velocity_m_s=velocity,
        lander_accel_m_s2=accel,
        accelerometer_m_s2=accel,
        pad_force_n=force,
        placed_load_kg=load,
        stage=stage,
    )


def _flies_as_mujoco(model: mujoco.MjModel, data: mujoco.MjData, frame_skip: int) -> bool:
    """Whether :func:`_free_flight` takes MuJoCo's own steps on ``model``: no force but the field on
    the lander off the pad (no joint spring, damper or friction loss, no actuator, no fluid, no
    contact margin), an integrator that is then semi-implicit Euler, and one control period from
    ``data`` the same to the last bit (a build of MuJoCo that fuses multiply-adds would differ)."""
    forces = (model.dof_damping, model.jnt_stiffness, model.dof_frictionloss, model.geom_margin, model.geom_gap)
    integrators = (mujoco.mjtIntegrator.mjINT_EULER, mujoco.mjtIntegrator.mjINT_IMPLICITFAST)
    if model.nu or model.opt.density or model.opt.viscosity or any(np.any(f) for f in forces):
        return False
    if model.opt.integrator not in integrators or data.ncon or data.qpos[0] <= CLEARANCE_M:
        return False
    probe = mujoco.MjData(model)
    probe.time, probe.qpos[0], probe.qvel[0] = data.time, data.qpos[0], data.qvel[0]
    mujoco.mj_forward(model, probe)
    ours = [np.zeros(1) for _ in range(4)]
    if _free_flight(*ours, 0, 0, frame_skip, model.opt.timestep, -math.inf, *_state(probe)) != 1:
        return False
    mujoco.mj_step(model, probe, nstep=frame_skip)
    return [float(x[0]) for x in ours] == list(_state(probe))


def _floor(scenario: Scenario, placed: int) -> float:
    """The lowest height of free flight with ``placed`` weights on: the clearance, or the height
    at which the next weight is placed (:meth:`~microg_env.scenarios.Scenario.loads_due`)."""
    if placed == len(scenario.loads):
        return CLEARANCE_M
    return max(CLEARANCE_M, scenario.loads[placed].height_m)  # only the first weights have none


def _state(data: mujoco.MjData) -> tuple[float, float, float, float]:
    """Time, height, speed and acceleration of the pad test's lander."""
    return data.time, data.qpos[0], data.qvel[0], data.qacc[0]


@jit
def _free_flight(time, height, velocity, accel, k, steps, frame_skip, h, floor, t, z, v, a):
    """Control periods ``k``, ``k + 1``, ... of free flight at ``a`` from time ``t``, height ``z``
    and speed ``v``, sampled into the arrays, as MuJoCo's steps would take them (semi-implicit
    Euler, to which ``implicitfast`` reduces without velocity-dependent forces), while every step
    starts above ``floor`` and every period ends above it; the number taken."""
    flown = 0
    while k + flown <= steps:
        tn, zn, vn = t, z, v
        for _ in range(frame_skip):
            if zn <= floor:
                return flown
            vn = vn + h * a
            zn = zn + h * vn
            tn = tn + h
        if zn <= floor:
            return flown
        t, z, v = tn, zn, vn
        i = k + flown
        time[i], height[i], velocity[i], accel[i] = t, z, v, a
        flown += 1
    return flown
