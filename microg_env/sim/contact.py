"""Closed-form spring-damper contact of Section 2 (Eqs. 1-16).

A mass M lands at speed V0 on a pad of stiffness K and damping D (Eq. 1: M d'' + D d' + K d = 0,
d(0) = 0, d'(0) = V0). With w = sqrt(K/M), xi = D / (2 sqrt(K M)), lambda = xi w and
w_d = w sqrt(1 - xi^2):

* deformation d(t) = (V0 / w_d) exp(-lambda t) sin(w_d t)                       (Eq. 4)
* its rate d'(t) = (V0 / w_d) exp(-lambda t) (w_d cos(w_d t) - lambda sin(w_d t)) (Eq. 5)
* contact force F = K d + D d'                                               (Eq. 1, Eq. 16)

A pad cannot pull, so the foot leaves when F returns to zero (Eq. 6), at
w_d t_s = pi - arctan(2 lambda w_d / (w_0^2 - 2 lambda^2)) = pi - 2 arctan(lambda / w_d) (Eq. 7),
with restitution c_r = |d'(t_s)| / V0 = exp(-lambda t_s) (Eq. 9, H = 1). Eq. (10) and Eq. (12)
are the paper's simpler approximations t* = pi / w_d and c_r = exp(-xi pi / sqrt(1 - xi^2)),
which ignore that the force reaches zero before the deformation does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from microg_env.validate import FieldError


def _check(mass_kg: float, stiffness_n_per_m: float, damping_n_s_per_m: float) -> None:
    for name, value in (
        ("mass", mass_kg),
        ("stiffness", stiffness_n_per_m),
        ("damping", damping_n_s_per_m),
    ):
        if not (math.isfinite(value) and value > 0):
            raise FieldError(f"{name} must be a positive finite number, got {value!r}", name)
    product = stiffness_n_per_m * mass_kg
    if not (math.isfinite(product) and product > 0 and math.isfinite(math.sqrt(stiffness_n_per_m / mass_kg))):
        raise FieldError(
            f"stiffness {stiffness_n_per_m!r} N/m and mass {mass_kg!r} kg are outside what floating point can take",
            "stiffness_n_per_m",
            "mass_kg",
        )
    ratio = damping_ratio(mass_kg, stiffness_n_per_m, damping_n_s_per_m)
    if ratio >= 1.0:
        raise FieldError(
            f"damping {damping_n_s_per_m!r} N s/m makes the pad over-damped (xi = {ratio:.3f} >= 1) for "
            f"mass {mass_kg!r} kg and stiffness {stiffness_n_per_m!r} N/m; Section 2 needs xi < 1",
            "damping_n_s_per_m",
            "stiffness_n_per_m",
            "mass_kg",
        )


def natural_frequency(mass_kg: float, stiffness_n_per_m: float) -> float:
    """w = sqrt(K / M), rad/s (Eq. 2)."""
    return math.sqrt(stiffness_n_per_m / mass_kg)


def damping_ratio(mass_kg: float, stiffness_n_per_m: float, damping_n_s_per_m: float) -> float:
    """xi = D / (2 sqrt(K M)) (Eq. 2)."""
    return damping_n_s_per_m / (2.0 * math.sqrt(stiffness_n_per_m * mass_kg))


@dataclass(frozen=True)
class SpringDamperContact:
    """The Section 2 contact of mass ``mass_kg`` on a pad (K, D), for any impact speed."""

    mass_kg: float
    stiffness_n_per_m: float
    damping_n_s_per_m: float

    def __post_init__(self) -> None:
        _check(self.mass_kg, self.stiffness_n_per_m, self.damping_n_s_per_m)

    @property
    def omega(self) -> float:
        """Undamped natural frequency w, rad/s."""
        return natural_frequency(self.mass_kg, self.stiffness_n_per_m)

    @property
    def xi(self) -> float:
        """Damping ratio xi."""
        return damping_ratio(self.mass_kg, self.stiffness_n_per_m, self.damping_n_s_per_m)

    @property
    def decay_rate(self) -> float:
        """lambda = D / (2 M) = xi w, 1/s (Eq. 3)."""
        return self.damping_n_s_per_m / (2.0 * self.mass_kg)

    @property
    def omega_d(self) -> float:
        """Damped frequency w_d = w sqrt(1 - xi^2), rad/s (Eq. 2)."""
        return self.omega * math.sqrt(1.0 - self.xi**2)

    def deformation(self, t: np.ndarray | float, impact_speed_m_s: float) -> np.ndarray | float:
        """d(t), m, while the linear model holds (Eq. 4)."""
        return impact_speed_m_s / self.omega_d * np.exp(-self.decay_rate * t) * np.sin(self.omega_d * t)

    def deformation_rate(self, t: np.ndarray | float, impact_speed_m_s: float) -> np.ndarray | float:
        """d'(t), m/s (Eq. 5)."""
        wd, lam = self.omega_d, self.decay_rate
        return impact_speed_m_s / wd * np.exp(-lam * t) * (wd * np.cos(wd * t) - lam * np.sin(wd * t))

    def force(self, deformation_m: np.ndarray | float, rate_m_s: np.ndarray | float) -> np.ndarray | float:
        """Contact force F = K d + D d', N (Eq. 1; Eq. 16 with D from Eq. 14)."""
        return self.stiffness_n_per_m * deformation_m + self.damping_n_s_per_m * rate_m_s

    @property
    def contact_time_s(self) -> float:
        """Time until the force returns to zero, t_s = (pi - 2 arctan(lambda / w_d)) / w_d (Eq. 7)."""
        return (math.pi - 2.0 * math.atan(self.decay_rate / self.omega_d)) / self.omega_d

    @property
    def restitution(self) -> float:
        """c_r = exp(-lambda t_s), the exact unilateral value (Eq. 9 with H = 1)."""
        return math.exp(-self.decay_rate * self.contact_time_s)

    @property
    def half_period_s(self) -> float:
        """The paper's approximation t* = pi / w_d (Eq. 10)."""
        return math.pi / self.omega_d

    @property
    def restitution_half_period(self) -> float:
        """The paper's approximation c_r = exp(-xi pi / sqrt(1 - xi^2)) (Eq. 12)."""
        return math.exp(-self.xi * math.pi / math.sqrt(1.0 - self.xi**2))

    @property
    def peak_time_s(self) -> float:
        """Time of the largest deformation, t_m = arctan(w_d / lambda) / w_d."""
        return math.atan2(self.omega_d, self.decay_rate) / self.omega_d

    def max_deformation_m(self, impact_speed_m_s: float) -> float:
        """Peak deformation (V0 / w) exp(-lambda t_m), m (Eq. 4 at d' = 0)."""
        return impact_speed_m_s / self.omega * math.exp(-self.decay_rate * self.peak_time_s)

    def max_deceleration_m_s2(self, impact_speed_m_s: float) -> float:
        """Peak contact force per unit mass (the collision acceleration), m/s^2.

        F / M = (V0 w^2 / w_d) exp(-lambda t) sin(w_d t + 2 theta) with theta = arctan(lambda / w_d),
        largest at w_d t_f = pi/2 - 3 theta, where it equals V0 w exp(-lambda t_f); for
        3 theta >= pi/2 the force only falls after impact and the peak is D V0 / M at t = 0.
        """
        theta = math.atan(self.decay_rate / self.omega_d)
        if 3.0 * theta >= math.pi / 2.0:
            return self.damping_n_s_per_m * impact_speed_m_s / self.mass_kg
        t_f = (math.pi / 2.0 - 3.0 * theta) / self.omega_d
        return impact_speed_m_s * self.omega * math.exp(-self.decay_rate * t_f)
