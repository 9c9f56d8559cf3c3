"""The controller interface: ``reset()``, then ``controller(observation, info) -> action``.

Every controller (the baselines and learned policies) reads only the observation, what the rig's
sensors give, never the simulator's truth, so that they are compared on equal terms by one harness.
:class:`Readings` decodes an observation into SI units. A controller that closes its loop on x
may take a setpoint (:class:`SetpointController`): the residual mode of the environment moves it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from microg_env.envs.observation import OBSERVATION_INDEX, OBSERVATION_SCALES
from microg_env.params import ScrewStageParams

#: Drive speed that the action +-1 stands for, m/s: the paper's rig's maximum (Section 4.1), a
#: fixed unit of the action whatever rig is simulated (a slower drive saturates on its own).
MAX_SPEED_M_S = ScrewStageParams().max_speed_m_per_s


class Controller(Protocol):
    """What the environment, the CLI and the evaluation harness drive."""

    def reset(self) -> None:
        """Forget the previous episode."""

    def __call__(self, observation: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        """The action for this observation, shape (1,), in [-1, 1]."""


class SetpointController(Controller, Protocol):
    """A controller holding x at ``setpoint_m`` (0 for the rig's purpose, x = 0)."""

    setpoint_m: float


@dataclass(frozen=True)
class Readings:
    """An observation in SI units (OBSERVATION_SCALES)."""

    x_m: float  # grating ruler
    x_rate_m_s: float
    support_position_m: float  # servo encoder, above touchdown
    support_velocity_m_s: float
    lander_accel_m_s2: float  # accelerometer, g removed, up positive
    pad_force_n: float
    foot_height_m: float
    placed_load_kg: float

    @classmethod
    def of(cls, observation: np.ndarray) -> Readings:
        def get(name: str) -> float:
            return float(observation[OBSERVATION_INDEX[name]]) * OBSERVATION_SCALES[name]

        return cls(
            get("x"),
            get("x_rate"),
            get("support_position"),
            get("support_velocity"),
            get("lander_accel"),
            get("pad_force"),
            get("height"),
            get("placed_load"),
        )
