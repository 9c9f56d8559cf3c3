"""The rig's sensors as the controller sees them: noise, quantisation and rates by backward difference.

Every function works on arrays over rigs, so one rig and a batch of rigs read their sensors through
the same code. The true values come as one (4, n) array, one row per sensor (:data:`SENSORS`); noise
is drawn from the caller's generator (MuJoCo adds none).
"""

from __future__ import annotations

import math

import numpy as np

from microg_env.params import RigParams

#: Rows of the sensor arrays: grating ruler (x, m), servo encoder (support position, m),
#: accelerometer (lander acceleration with g removed, m/s^2), pad force sensor (N).
SENSORS = ("ruler", "encoder", "accelerometer", "pad_force")


class SensorModel:
    """Noise and resolution of each sensor per control period (SensorParams, Section 4.1)."""

    def __init__(self, params: RigParams, control_period_s: float, noisy: bool) -> None:
        sensors, screw = params.sensors, params.screw
        accelerometer = sensors.accelerometer_noise_density_m_s2_per_sqrt_hz * math.sqrt(0.5 / control_period_s)
        #: RMS noise per reading of each sensor (the encoder is exact but quantised).
        self.noise = np.array([[sensors.ruler_noise_m], [0.0], [accelerometer], [sensors.force_noise_n]])
        #: Quantisation steps of ruler and encoder, m.
        self.steps = np.array(
            [[sensors.ruler_resolution_m], [screw.lead_m / screw.belt_ratio / sensors.encoder_counts_per_rev]]
        )
        self.noisy = noisy  # False: exact readings (the sensor-noise imperfection off)

    def read(self, rng: np.random.Generator, truth: np.ndarray) -> np.ndarray:
        """Readings (4, n) of n rigs' true values ``truth`` (4, n): noise added, ruler and encoder quantised."""
        if not self.noisy:
            return truth
        readings = truth + self.noise * rng.standard_normal(truth.shape)
        readings[:2] = np.rint(readings[:2] / self.steps) * self.steps
        return readings


def backward_difference(value: np.ndarray, previous: np.ndarray | None, period_s: float) -> np.ndarray:
    """(value - previous) / period, zero on the first sample (``previous`` None)."""
    if previous is None:
        return np.zeros_like(value)
    return (value - previous) / period_s
