"""The perfect follower: a support that follows the lander so that x stays exactly 0.

It adds to the screw joint the generalised force that gives the QZS joint zero acceleration under
every smooth force (gravity, springs, loads, the servo's own torque), then removes the rounding
drift by handing any residual x to the support coordinate; the lander's own state is never
touched. With x = 0 the QZS and balancer force is constant, so the lander descends at
a = m_ext g / (M + m_ext): this is the rig's upper bound, against which real controllers and the
model's force balance are checked. It does not anticipate contact forces.
"""

from __future__ import annotations

import mujoco
import numpy as np

from microg_env.sim.model import Rig


class PerfectFollower:
    """Steps a rig's data with the support following the lander perfectly."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self._unit = np.zeros((1, rig.model.nv))
        self._unit[0, rig.screw_dof] = 1.0
        self._response = np.zeros((1, rig.model.nv))

    def step(self, data: mujoco.MjData) -> None:
        """Advance ``data`` (made for ``rig.model``) by one physics step."""
        rig, model = self.rig, self.rig.model
        screw, qzs = rig.screw_dof, rig.qzs_dof
        data.qfrc_applied[screw] = 0.0
        mujoco.mj_forward(model, data)
        mujoco.mj_solveM(model, data, self._response, self._unit)
        data.qfrc_applied[screw] = -data.qacc_smooth[qzs] / self._response[0, qzs]
        mujoco.mj_step(model, data)
        # Hand any residual x to the support so the lander's absolute state is unchanged.
        data.qpos[rig.screw_qpos] += data.qpos[rig.qzs_qpos]
        data.qpos[rig.qzs_qpos] = 0.0
        data.qvel[screw] += data.qvel[qzs]
        data.qvel[qzs] = 0.0
