"""The ideal reference's free flight (sim/reference.py): MuJoCo's own steps, bit for bit, faster."""

from __future__ import annotations

import numpy as np
import pytest

from microg_env.params import RigParams
from microg_env.scenarios import CONDITIONS, HELD_OUT, LoadStep, Scenario
from microg_env.sim import reference
from microg_env.trajectory import CHANNELS

PARAMS = RigParams()
CASES = {
    "condition 1": (CONDITIONS[1], 12.0),
    "condition 3 (a weight placed at 25 mm, 8.7 s)": (CONDITIONS[3], 12.0),
    "three stages, two placed in flight": (HELD_OUT["three-stage"], None),
    "two weights placed in flight, 4 and 2 mm apart": (
        Scenario("close", (LoadStep(0.2), LoadStep(0.1, 0.006), LoadStep(0.05, 0.004)), descent_height_m=0.06),
        6.0,
    ),
}


def _simulated(scenario: Scenario, duration_s: float | None, monkeypatch, free: bool):
    duration_s = scenario.duration_s if duration_s is None else duration_s
    if not free:
        monkeypatch.setattr(reference, "_free_flight", lambda *args: 0)
    try:
        return reference._simulate(scenario, PARAMS, 1e-3, 1e-4, round(duration_s / 1e-3))
    finally:
        monkeypatch.undo()


@pytest.mark.parametrize("case", CASES)
def test_free_flight_is_mujocos_own_steps_bit_for_bit(case, monkeypatch):
    """Between contacts the reference steps the lander itself (v += h a, z += h v); every channel of
    every sample is what stepping MuJoCo throughout gives, through touchdowns, bounces and weights
    placed in flight and on the pad."""
    scenario, duration_s = CASES[case]
    fast = _simulated(scenario, duration_s, monkeypatch, free=True)
    mujoco_only = _simulated(scenario, duration_s, monkeypatch, free=False)
    for name in CHANNELS:
        assert np.array_equal(getattr(fast, name), getattr(mujoco_only, name)), name
    assert np.count_nonzero(np.diff(fast.stage)) == np.count_nonzero(np.diff(mujoco_only.stage))


def test_most_of_a_landing_is_flown_without_mujoco(monkeypatch):
    """Condition 1's 30 s: the lander is on the pad for a sixth of it, and the reference steps
    MuJoCo only near and on the pad (it stepped MuJoCo throughout, 0.9 s of the 1.7 s of a run)."""
    flown = []
    free_flight = reference._free_flight

    def counted(*args):
        flown.append(free_flight(*args))
        return flown[-1]

    monkeypatch.setattr(reference, "_free_flight", counted)
    trajectory = reference._simulate(CONDITIONS[1], PARAMS, 1e-3, 1e-4, 30_000)
    in_contact = int((trajectory.pad_force_n != 0).sum())
    assert 0.1 < in_contact / 30_000 < 0.3
    assert sum(flown) > 0.7 * 30_000
    assert sum(flown) + in_contact <= 30_000


def test_free_flight_is_taken_only_where_it_is_mujocos_step():
    """A damped joint, another integrator, a contact margin or a lander starting on the pad: the
    reference steps MuJoCo throughout (the free flight's arithmetic would not be MuJoCo's)."""
    import mujoco

    from microg_env.sim.model import build_pad_test

    def flies(change=None, height=0.05):
        model = build_pad_test(PARAMS).model
        if change is not None:
            change(model)
        data = mujoco.MjData(model)
        data.qpos[0] = height
        mujoco.mj_forward(model, data)
        return reference._flies_as_mujoco(model, data, 10)

    assert flies()
    assert not flies(lambda m: m.dof_damping.__setitem__(0, 1.0))
    assert not flies(lambda m: setattr(m.opt, "integrator", mujoco.mjtIntegrator.mjINT_RK4))
    assert not flies(lambda m: m.geom_margin.__setitem__(slice(None), 1e-3))
    assert not flies(height=0.0)
