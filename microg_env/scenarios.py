"""Test conditions: the paper's three (Table 2, Section 3.2) and custom load schedules.

A scenario starts the rig balanced with the foot ``descent_height_m`` above the pad; each test
weight of ``loads`` is placed either at t = 0 (``height_m`` None) or when the foot comes down to
``height_m`` above the pad. The weights placed so far make the load stage, whose ideal descent is
m g / (M + m) with m their total (Table 2).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

from microg_env.params import RigParams


@dataclass(frozen=True)
class LoadStep:
    """A test weight and when it is placed: at t = 0 (``height_m`` None) or at that foot height."""

    mass_kg: float
    height_m: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.mass_kg, int | float) and math.isfinite(self.mass_kg) and self.mass_kg > 0):
            raise ValueError(f"LoadStep.mass_kg must be a positive finite number of kg, got {self.mass_kg!r}")
        if self.height_m is not None and not (
            isinstance(self.height_m, int | float) and math.isfinite(self.height_m) and self.height_m > 0
        ):
            raise ValueError(f"LoadStep.height_m must be None or a positive height in m, got {self.height_m!r}")


@dataclass(frozen=True)
class Scenario:
    """A test: start height, load schedule, lander and pad."""

    name: str
    loads: tuple[LoadStep, ...]
    descent_height_m: float
    lander_mass_kg: float = 620.0  # Table 1
    pad_stiffness_n_per_m: float = 4666.0  # Table 1
    pad_damping_n_s_per_m: float = 200.0  # Table 1
    duration_s: float = 30.0  # Section 3.2: 30 s of simulated time

    def __post_init__(self) -> None:
        if not isinstance(self.loads, tuple) or not self.loads:
            raise ValueError(f"Scenario.loads must be a non-empty tuple of LoadStep, got {self.loads!r}")
        for load in self.loads:
            if not isinstance(load, LoadStep):
                raise ValueError(f"Scenario.loads must hold LoadStep items, got {load!r}")
        for name in ("descent_height_m", "lander_mass_kg", "pad_stiffness_n_per_m", "pad_damping_n_s_per_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"Scenario.{name} must be a positive finite number, got {value!r}")
        if not (isinstance(self.duration_s, int | float) and 0 < self.duration_s <= 600):
            raise ValueError(f"Scenario.duration_s must be in (0, 600] s, got {self.duration_s!r}")
        heights = [math.inf if load.height_m is None else load.height_m for load in self.loads]
        if heights != sorted(heights, reverse=True):
            raise ValueError("Scenario.loads must be in the order they are placed: t = 0 first, then by falling height")
        for load in self.loads:
            if load.height_m is not None and load.height_m >= self.descent_height_m:
                raise ValueError(
                    f"Scenario.loads height {load.height_m!r} m must be below the descent height "
                    f"{self.descent_height_m!r} m (use None to place a weight at t = 0)"
                )
        if self.loads[0].height_m is not None:
            raise ValueError("Scenario.loads: the first weight must be placed at t = 0 (height None)")

    @property
    def stages_kg(self) -> tuple[float, ...]:
        """Total external load of each stage, kg (the weights placed so far)."""
        return tuple(itertools.accumulate(load.mass_kg for load in self.loads))

    def loads_due(self, height_m: float, placed: int) -> int:
        """How many weights are on the lander once its foot is at ``height_m``, ``placed`` being on."""
        while placed < len(self.loads):
            due = self.loads[placed].height_m
            if due is not None and height_m > due:
                break
            placed += 1
        return placed

    @property
    def loads_kg(self) -> tuple[float, ...]:
        return tuple(load.mass_kg for load in self.loads)

    def ideal_descent_m_s2(self, gravity_m_s2: float) -> tuple[float, ...]:
        """Ideal descent acceleration of each load stage, m g / (M + m), signed up positive."""
        return tuple(-m * gravity_m_s2 / (self.lander_mass_kg + m) for m in self.stages_kg)

    def rig_params(self, base: RigParams | None = None) -> RigParams:
        """``base`` (default: the paper's rig) with this scenario's lander mass and pad."""
        base = RigParams() if base is None else base
        pad = replace(
            base.pad, stiffness_n_per_m=self.pad_stiffness_n_per_m, damping_n_s_per_m=self.pad_damping_n_s_per_m
        )
        return replace(base, lander=replace(base.lander, mass_kg=self.lander_mass_kg), pad=pad)


#: The paper's test conditions (Table 2; Section 3.2 for condition 3's second stage at 25 mm).
CONDITIONS: dict[int, Scenario] = {
    1: Scenario("condition 1", (LoadStep(0.49),), descent_height_m=0.09),
    2: Scenario("condition 2", (LoadStep(1.0),), descent_height_m=0.09),
    3: Scenario("condition 3", (LoadStep(0.05), LoadStep(1.0, height_m=0.025)), descent_height_m=0.055),
}


def condition(number: int) -> Scenario:
    """The paper's condition 1, 2 or 3."""
    if number not in CONDITIONS:
        raise ValueError(f"condition must be 1, 2 or 3, got {number!r}")
    return CONDITIONS[number]
