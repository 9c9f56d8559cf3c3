"""The MuJoCo pad contact against the Section 2 spring-damper: impact and static sink."""

from dataclasses import replace

import mujoco
import pytest

from microg_env.params import PadParams, RigParams
from microg_env.sim.drop import drop_test, static_sink
from microg_env.sim.model import build_pad_test

# (M, K, D): the paper's lander and pad, a lighter stiffer set, and a light soft one.
PADS = [(620.0, 4666.0, 200.0), (300.0, 10000.0, 500.0), (100.0, 2000.0, 50.0)]
SPEEDS = [0.005, 0.02, 0.0373, 0.06]


@pytest.mark.parametrize("speed", SPEEDS)
@pytest.mark.parametrize(("mass", "stiffness", "damping"), PADS)
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
    for _ in range(2000):
        penetrating = data.qpos[0] < 0  # contacts found in a step belong to its starting state
        mujoco.mj_step(pad_test.model, data)
        if penetrating:
            counts.add(data.ncon)
    assert counts == {pad_test.pad_contacts}


@pytest.mark.parametrize("load", [0.49, 4.9, 49.0])
@pytest.mark.parametrize(("stiffness", "damping"), [(4666.0, 200.0), (10000.0, 900.0)])
def test_static_sink_is_load_over_stiffness(load, stiffness, damping):
    params = replace(RigParams(), pad=PadParams(stiffness_n_per_m=stiffness, damping_n_s_per_m=damping))
    assert static_sink(params, load) == pytest.approx(load / stiffness, rel=0.02)


def test_static_sink_exposes_the_impedance_trap():
    # With MuJoCo's usual impedance the impact can be tuned right while the sink is far off:
    # the solver scales every other force by about (1 - d) / (1 + (n - 1) d).
    params = replace(RigParams(), pad=replace(PadParams(), impedance=0.3))
    sink = static_sink(params, 4.9)
    assert sink < 0.5 * 4.9 / 4666.0
