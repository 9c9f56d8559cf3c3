"""A run recorded at every control step: the one data structure metrics, plots and reports read."""

from __future__ import annotations

import operator
from dataclasses import dataclass

import numpy as np

from microg_env.scenarios import Scenario

#: Recorded channels, all SI, up positive, one sample per control step (index 0: the reset state).
CHANNELS = (
    "time_s",
    "foot_height_m",
    "lander_velocity_m_s",
    "lander_accel_m_s2",
    "accelerometer_m_s2",
    "x_m",
    "support_position_m",
    "support_velocity_m_s",
    "support_force_deviation_n",
    "pad_force_n",
    "placed_load_kg",
    "stage",
    "command_m_s",
    "servo_torque_n_m",
    "reward",
)


@dataclass(frozen=True)
class Trajectory:
    """Sampled channels of one run plus what is needed to interpret them."""

    scenario: Scenario
    gravity_m_s2: float
    lander_mass_kg: float
    time_s: np.ndarray
    foot_height_m: np.ndarray
    lander_velocity_m_s: np.ndarray
    lander_accel_m_s2: np.ndarray
    accelerometer_m_s2: np.ndarray  # what the lander's accelerometer reads (bias and noise), g removed
    x_m: np.ndarray
    support_position_m: np.ndarray
    support_velocity_m_s: np.ndarray
    support_force_deviation_n: np.ndarray
    pad_force_n: np.ndarray
    placed_load_kg: np.ndarray
    stage: np.ndarray
    command_m_s: np.ndarray
    servo_torque_n_m: np.ndarray
    reward: np.ndarray
    termination_reason: str | None = None

    def __len__(self) -> int:
        return int(self.time_s.size)

    @classmethod
    def from_channels(
        cls, scenario: Scenario, gravity_m_s2: float, lander_mass_kg: float, **channels: np.ndarray
    ) -> Trajectory:
        """A trajectory of the given channels, every other one zero (e.g. a landing with no rig)."""
        size = len(channels["time_s"])
        arrays = {name: np.zeros(size) for name in CHANNELS} | channels
        arrays["stage"] = np.asarray(arrays["stage"]).astype(int)
        return cls(scenario, gravity_m_s2, lander_mass_kg, **arrays)

    @classmethod
    def from_rows(
        cls,
        scenario: Scenario,
        gravity_m_s2: float,
        lander_mass_kg: float,
        rows: np.ndarray,
        rewards: np.ndarray,
        termination_reason: str | None = None,
    ) -> Trajectory:
        """A run's trajectory from one row per step of every channel but the reward, in
        :data:`CHANNELS`' order, and the rewards; new arrays."""
        arrays = {name: column.copy() for name, column in zip(CHANNELS[:-1], rows.T, strict=True)}
        arrays["reward"] = np.array(rewards, dtype=np.float64)
        arrays["stage"] = arrays["stage"].astype(int)
        return cls(scenario, gravity_m_s2, lander_mass_kg, termination_reason=termination_reason, **arrays)


class TrajectoryRecorder:
    """The channels of the environment's ``info`` dictionaries, one row per step."""

    def __init__(self) -> None:
        self._rows: list[tuple] = []
        self._rewards: list[float] = []
        self._read = operator.itemgetter(*CHANNELS[:-1])

    def append(self, info: dict, reward: float = 0.0) -> None:
        self._rows.append(self._read(info))
        self._rewards.append(reward)

    def finish(
        self, scenario: Scenario, gravity_m_s2: float, lander_mass_kg: float, termination_reason: str | None = None
    ) -> Trajectory:
        rows = np.array(self._rows, dtype=np.float64).reshape(-1, len(CHANNELS) - 1)
        rewards = np.array(self._rewards, dtype=np.float64)
        return Trajectory.from_rows(scenario, gravity_m_s2, lander_mass_kg, rows, rewards, termination_reason)
