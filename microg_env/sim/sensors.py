"""The rig's sensors as the controller sees them: noise, quantisation and rates by backward difference.

Every function works on arrays over rigs, so one rig and a batch of rigs read their sensors through
the same code. The true values come as one (4, n) array, one row per sensor (:data:`SENSORS`); noise
is drawn from the caller's generator (MuJoCo adds none).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

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
        #: Constant offset of each reading (the accelerometer's bias).
        self.bias = np.array([[0.0], [0.0], [sensors.accelerometer_bias_m_s2], [0.0]])
        #: Quantisation steps of ruler and encoder, m.
        self.steps = np.array(
            [[sensors.ruler_resolution_m], [screw.lead_m / screw.belt_ratio / sensors.encoder_counts_per_rev]]
        )
        self.noisy = noisy  # False: exact readings (the sensor-noise imperfection off)

    def read(self, truth: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
        """Readings (4, n) of n rigs' true values ``truth`` (4, n): bias and noise added (``normals``,
        (4, n) standard normal draws), ruler and encoder quantised."""
        if not self.noisy:
            return truth
        readings = truth + self.bias + self.noise * normals
        readings[:2] = np.rint(readings[:2] / self.steps) * self.steps
        return readings


class NoiseDraws:
    """Standard normal draws for the sensors, one (4,) per rig and control period, taken from each
    rig's own generator :data:`NOISE_BLOCK` periods at a time (one call per rig per block, not per
    period). :meth:`restart` at a reset makes a rig's next period draw a fresh block, after what
    the reset itself drew."""

    def __init__(self, num_rigs: int) -> None:
        self.block = np.zeros((num_rigs, NOISE_BLOCK, len(SENSORS)))
        self.used = np.full(num_rigs, NOISE_BLOCK)

    def restart(self, ids: np.ndarray) -> None:
        self.used[ids] = NOISE_BLOCK

    def draw(self, ids: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        """The next draws (4, n) of rigs ``ids``."""
        used = self.used[ids]
        for i in ids[used >= NOISE_BLOCK]:
            self.block[i] = rngs[i].standard_normal((NOISE_BLOCK, len(SENSORS)))
            self.used[i] = 0
        used = self.used[ids]
        self.used[ids] = used + 1
        return self.block[ids, used].T


#: Control periods of sensor noise drawn at once per rig.
NOISE_BLOCK = 1000
