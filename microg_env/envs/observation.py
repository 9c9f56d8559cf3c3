"""The environment's observation: what the rig's sensors give, each divided by a scale.

One owner for the layout, read by the environment (which writes it) and the controllers (which
decode it: the compiled PID and feed-forward by column, Python controllers with
:class:`microg_env.controllers.base.Readings`).
"""

from __future__ import annotations

import numpy as np

from microg_env.params import ScrewStageParams

#: Observation entries and the scale each is divided by (SI units / scale = order one).
OBSERVATION_SCALES: dict[str, float] = {
    "x": 1e-4,  # grating ruler, m (100 um)
    "x_rate": 1e-3,  # its backward difference, m/s
    "support_position": 0.1,  # servo encoder, m above touchdown
    "support_velocity": 0.1,  # encoder backward difference, m/s
    "lander_accel": 0.1,  # accelerometer with g removed, m/s^2 (up positive)
    "pad_force": 100.0,  # pad force sensor, N
    "height": 0.1,  # foot height from encoder + ruler, m
    "placed_load": 1.0,  # test weights placed so far, kg
    "previous_action": 1.0,  # the agent's previous action
    # the base controller's speed command (residual mode; else 0), m/s: the paper's maximum speed
    "base_command": ScrewStageParams().max_speed_m_per_s,
}
OBSERVATION_INDEX = {name: i for i, name in enumerate(OBSERVATION_SCALES)}
#: The rig's sensor sets, by the observation entries each lacks (they read 0). ``extended``: every
#: sensor above; ``paper``: the paper's rig, which closes its loops on the grating ruler and the
#: servo encoder only (Section 4.1), with no pad force sensor and no accelerometer.
SENSOR_SETS: dict[str, tuple[str, ...]] = {"extended": (), "paper": ("lander_accel", "pad_force")}
SCALES = np.array(list(OBSERVATION_SCALES.values()))
