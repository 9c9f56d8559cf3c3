"""The closed-form contact of Section 2 against its own defining equations."""

import math

import numpy as np
import pytest

from microg_env.params import flat_punch_radius_m
from microg_env.sim.contact import SpringDamperContact

PAPER = SpringDamperContact(620.0, 4666.0, 200.0)
SPEED = 0.0373


def test_paper_pad_values():
    # xi = D / (2 sqrt(K M)) and t* = pi / w_d for Table 1 (DESIGN.md quotes 0.059 and 1.147 s).
    assert PAPER.xi == pytest.approx(200.0 / (2.0 * math.sqrt(4666.0 * 620.0)))
    assert PAPER.xi == pytest.approx(0.0588, abs=1e-4)
    assert PAPER.half_period_s == pytest.approx(1.1472, abs=1e-4)
    assert PAPER.restitution_half_period == pytest.approx(0.8311, abs=1e-4)
    # Peak deformation per unit impact speed: about 0.333 mm per mm/s.
    assert PAPER.max_deformation_m(1e-3) == pytest.approx(0.3335e-3, rel=1e-3)


def test_deformation_solves_equation_1():
    t = np.linspace(0.0, PAPER.contact_time_s, 2001)
    d = PAPER.deformation(t, SPEED)
    rate = PAPER.deformation_rate(t, SPEED)
    accel = np.gradient(rate, t)
    residual = PAPER.mass_kg * accel + PAPER.damping_n_s_per_m * rate + PAPER.stiffness_n_per_m * d
    assert np.max(np.abs(residual[5:-5])) < 1e-5 * PAPER.stiffness_n_per_m * PAPER.max_deformation_m(SPEED)
    assert d[0] == 0.0
    assert rate[0] == pytest.approx(SPEED)
    assert np.allclose(np.gradient(d, t)[5:-5], rate[5:-5], rtol=0, atol=1e-6 * SPEED)


def test_contact_ends_where_the_force_vanishes():
    t_s = PAPER.contact_time_s
    force = PAPER.force(PAPER.deformation(t_s, SPEED), PAPER.deformation_rate(t_s, SPEED))
    assert abs(force) < 1e-9
    t = np.linspace(0.0, t_s, 1001)[1:-1]
    assert np.all(PAPER.force(PAPER.deformation(t, SPEED), PAPER.deformation_rate(t, SPEED)) > 0)
    # The force vanishes before the deformation does: Eq. (7) is shorter than Eq. (10).
    assert t_s < PAPER.half_period_s
    assert PAPER.deformation(t_s, SPEED) > 0


def test_restitution_is_the_exit_speed_ratio():
    exit_rate = PAPER.deformation_rate(PAPER.contact_time_s, SPEED)
    assert -exit_rate / SPEED == pytest.approx(PAPER.restitution, rel=1e-12)
    assert PAPER.restitution > PAPER.restitution_half_period


def test_peak_deformation_and_deceleration_are_the_maxima():
    t = np.linspace(0.0, PAPER.contact_time_s, 200001)
    d = PAPER.deformation(t, SPEED)
    force = PAPER.force(d, PAPER.deformation_rate(t, SPEED))
    assert PAPER.max_deformation_m(SPEED) == pytest.approx(d.max(), rel=1e-9)
    assert PAPER.deformation_rate(PAPER.peak_time_s, SPEED) == pytest.approx(0.0, abs=1e-15)
    assert PAPER.max_deceleration_m_s2(SPEED) == pytest.approx(force.max() / PAPER.mass_kg, rel=1e-9)


def test_heavily_damped_peak_force_is_at_impact():
    contact = SpringDamperContact(10.0, 100.0, 55.0)  # xi = 0.87: 3 theta > pi/2
    assert contact.max_deceleration_m_s2(0.1) == pytest.approx(55.0 * 0.1 / 10.0)


def test_approximations_converge_for_light_damping():
    light = SpringDamperContact(620.0, 4666.0, 1.0)
    assert light.contact_time_s == pytest.approx(light.half_period_s, rel=1e-3)
    assert light.restitution == pytest.approx(light.restitution_half_period, rel=1e-5)


@pytest.mark.parametrize(
    ("mass", "stiffness", "damping", "word"),
    [
        (0.0, 4666.0, 200.0, "mass"),
        (620.0, -1.0, 200.0, "stiffness"),
        (620.0, 4666.0, float("nan"), "damping"),
        (620.0, 4666.0, 4000.0, "over-damped"),
    ],
)
def test_bad_contact_parameters_are_named(mass, stiffness, damping, word):
    with pytest.raises(ValueError, match=word):
        SpringDamperContact(mass, stiffness, damping)


def test_foot_radius_is_the_flat_punch_of_table_1():
    radius = flat_punch_radius_m(4666.0, 3.3e4, 0.25)
    assert radius == pytest.approx(0.0663, abs=1e-4)
    assert 2.0 * radius * 3.3e4 / (1.0 - 0.25**2) == pytest.approx(4666.0)
