"""The MuJoCo pad contact against the Section 2 spring-damper: impact, static sink, full depth."""

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from microg_env.params import MIN_STEPS_PER_CONTACT, PHYSICS_STEP_S, PadParams, RigParams
from microg_env.sim.contact import SpringDamperContact
from microg_env.sim.drop import drop_test, simulate_drop, static_sink
from microg_env.sim.model import build_pad_test

# (M, K, D): the paper's lander and pad, a lighter stiffer set, and a light soft one.
PADS = [(620.0, 4666.0, 200.0), (300.0, 10000.0, 500.0), (100.0, 2000.0, 50.0)]
SPEEDS = [0.005, 0.02, 0.0373, 0.06]


@pytest.mark.parametrize("speed", SPEEDS)
@pytest.mark.parametrize(("mass", "stiffness", "damping"), PADS)
@pytest.mark.slow
def test_drop_matches_closed_form(mass, stiffness, damping, speed):
    report = drop_test(mass, stiffness, damping, speed)
    assert abs(report.contact_time_s.rel_error) < 0.01
    assert abs(report.restitution.rel_error) < 0.01
    assert abs(report.max_deformation_m.rel_error) < 0.01
    assert abs(report.fitted_stiffness_n_per_m.rel_error) < 0.02
    assert abs(report.fitted_damping_n_s_per_m.rel_error) < 0.02


def test_flat_foot_makes_several_contact_points_throughout_the_impact():
    # The reason the contact law is divided among points: each point is its own spring.
    pad_test = build_pad_test()
    assert pad_test.pad_contacts > 1
    data = mujoco.MjData(pad_test.model)
    data.qvel[0] = -0.06
    counts = set()
    for _ in range(10000):
        penetrating = data.qpos[0] < 0  # contacts found in a step belong to its starting state
        mujoco.mj_step(pad_test.model, data)
        if penetrating:
            counts.add(data.ncon)
    assert counts == {pad_test.pad_contacts}


@pytest.mark.parametrize("load", [0.49, 4.9, 49.0])
@pytest.mark.parametrize(("stiffness", "damping"), [(4666.0, 200.0), (10000.0, 900.0)])
@pytest.mark.slow
def test_static_sink_is_load_over_stiffness(load, stiffness, damping):
    params = replace(RigParams(), pad=PadParams(stiffness_n_per_m=stiffness, damping_n_s_per_m=damping))
    # six decay times leave e^-6 = 0.25 % of the ringing: 0.10-0.15 % off (0.03 % after the default 12)
    assert static_sink(params, load, settle_decays=6.0) == pytest.approx(load / stiffness, rel=0.005)


@pytest.mark.slow
def test_static_sink_exposes_the_impedance_trap():
    # With MuJoCo's usual impedance the impact can be tuned right while the sink is far off:
    # the solver scales every other force by about (1 - d) / (1 + (n - 1) d).
    params = replace(RigParams(), pad=replace(PadParams(), impedance=0.3))
    sink = static_sink(params, 4.9, settle_decays=6.0)  # 0.44 of load / K
    assert sink < 0.5 * 4.9 / 4666.0


def test_deep_drop_never_pulls_the_lander():
    """At 250 mm/s the foot sinks 83 mm into the 100 mm pad: the old box pad flipped its contact
    normal past 75 mm and pulled the lander through (restitution -0.84). The half-space pad pushes
    at every depth, and the drop matches the closed form."""
    report = drop_test(620.0, 4666.0, 200.0, 0.25)
    assert report.max_deformation_m.sim == pytest.approx(0.08337, rel=1e-3)
    assert abs(report.restitution.rel_error) < 0.01
    trace = report.trace
    contact = SpringDamperContact(620.0, 4666.0, 200.0)
    pressing = trace.force_n > 0
    expected = contact.force(-trace.height_m[pressing], -trace.velocity_m_s[pressing])
    np.testing.assert_allclose(trace.force_n[pressing], expected, rtol=2e-3, atol=0.5)
    assert np.all(trace.force_n >= 0.0)


def test_drop_rejects_what_the_pad_cannot_take():
    with pytest.raises(ValueError, match="thickness"):
        drop_test(620.0, 4666.0, 200.0, 0.32)  # would sink 107 mm
    with pytest.raises(ValueError, match="stiffness"):
        drop_test(620.0, 1e300, 200.0, 0.04)
    with pytest.raises(ValueError, match="velocity"):
        drop_test(620.0, 4666.0, 200.0, 1e-9)  # would run for ever before: now below what it resolves


@pytest.mark.parametrize("stiffness", [4666.0, 1e6, 1.4e7])
def test_no_pad_the_physics_step_accepts_creates_energy(stiffness):
    """With at least MIN_STEPS_PER_CONTACT physics steps per contact the rebound never exceeds the
    impact; at K = 1e10 N/m and a 0.5 ms step the old rig rebounded 3.8 times its drop height."""
    contact = SpringDamperContact(620.0, stiffness, 1.0)  # nearly undamped: the hardest case
    assert contact.contact_time_s / PHYSICS_STEP_S >= MIN_STEPS_PER_CONTACT
    params = replace(RigParams(), pad=PadParams(stiffness_n_per_m=stiffness, damping_n_s_per_m=1.0))
    trace = simulate_drop(build_pad_test(params), 0.04, 2.0 * contact.contact_time_s)
    assert trace.velocity_m_s[-1] <= 0.04 * (1 + 1e-5)
