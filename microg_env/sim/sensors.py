"""The rig's sensors as the controller sees them: noise, quantisation and resolution per sensor.

:class:`SensorModel` holds each sensor's noise, bias and resolution (the readings themselves are
taken, for every rig at once, by the compiled control period,
:func:`microg_env.envs.period.observe`); :class:`NoiseDraws` holds each rig's standard normal
draws, taken from the rig's own generator (MuJoCo adds no noise).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from microg_env.params import RigParams

#: The sensors, in the order of the noise arrays: grating ruler (x, m), servo encoder (support
#: position, m), accelerometer (lander acceleration with g removed, m/s^2), pad force sensor (N).
SENSORS = ("ruler", "encoder", "accelerometer", "pad_force")


class SensorModel:
    """Noise and resolution of each sensor per control period (SensorParams, Section 4.1)."""

    def __init__(self, params: RigParams, control_period_s: float, noisy: bool) -> None:
        sensors, screw = params.sensors, params.screw
        accelerometer = sensors.accelerometer_noise_density_m_s2_per_sqrt_hz * math.sqrt(0.5 / control_period_s)
        #: RMS noise per reading of each sensor (the encoder is exact but quantised).
        self.noise = np.array([sensors.ruler_noise_m, 0.0, accelerometer, sensors.force_noise_n])
        #: Constant offset of each reading (the ruler's zero, the accelerometer's bias).
        self.bias = np.array([sensors.ruler_zero_offset_m, 0.0, sensors.accelerometer_bias_m_s2, 0.0])
        #: Quantisation steps of ruler and encoder, m.
        self.steps = np.array(
            [sensors.ruler_resolution_m, screw.lead_m / screw.belt_ratio / sensors.encoder_counts_per_rev]
        )
        self.noisy = noisy  # False: exact readings (the sensor-noise imperfection off: no bias either)


class NoiseDraws:
    """Standard normal draws for the sensors, one (4,) per rig and control period, taken from each
    rig's own generator :data:`NOISE_BLOCK` periods at a time (one call per rig per block, not per
    period). A block is drawn when it is first needed: :meth:`restart` at a reset makes a rig's next
    period draw a fresh block, after what the reset itself drew."""

    def __init__(self, num_rigs: int) -> None:
        self.block = np.zeros((num_rigs, NOISE_BLOCK, len(SENSORS)))
        self.used = np.full(num_rigs, NOISE_BLOCK)
        #: Whether some rig has used up its block (its next reading needs :meth:`refill` first).
        self.exhausted = True

    def restart(self, ids: np.ndarray) -> None:
        self.used[ids] = NOISE_BLOCK
        self.exhausted = True

    def refill(self, ids: np.ndarray, rngs: Sequence[np.random.Generator]) -> None:
        """Draw a new block for each of rigs ``ids`` that has used up its own."""
        for i in ids[self.used[ids] >= NOISE_BLOCK]:
            self.block[i] = rngs[i].standard_normal((NOISE_BLOCK, len(SENSORS)))
            self.used[i] = 0
        self.exhausted = bool((self.used >= NOISE_BLOCK).any())


#: Control periods of sensor noise drawn at once per rig.
NOISE_BLOCK = 1000
