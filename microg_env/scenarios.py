"""Test schedules: the paper's three conditions (Table 2, Section 3.2) and custom ones.

A scenario is a schedule, not a rig: it starts the rig balanced with the foot
``descent_height_m`` above the pad and places each test weight of ``loads`` either at t = 0
(``height_m`` None) or when the foot comes down to ``height_m`` above the pad. The weights placed
so far make the load stage, whose ideal descent is m g / (M + m) with m their total (Table 2) and
M the lander's mass, which belongs to the rig (:class:`~microg_env.params.RigParams`). A scenario
may name explicit ``overrides`` of rig parameters by dotted path (``{"pad.stiffness_n_per_m":
8000.0}``); nothing else in it touches the rig.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from microg_env import validate
from microg_env.params import RigParams, parameter_paths, with_overrides

#: Shortest and longest test a scenario may schedule, s.
MIN_DURATION_S, MAX_DURATION_S = 0.01, 600.0
#: Lowest start or switch height, m: a foot 0.1 mm above the pad is as good as on it.
MIN_HEIGHT_M = 1.0e-4
#: Lightest test weight, kg: 1 g makes a 1.6e-6 g field on the 620 kg lander, far below the
#: rig's 1e-4 g level (Conclusions).
MIN_LOAD_KG = 1.0e-3


@dataclass(frozen=True)
class LoadStep:
    """A test weight and when it is placed: at t = 0 (``height_m`` None) or at that foot height."""

    mass_kg: float
    height_m: float | None = None

    def __post_init__(self) -> None:
        validate.at_least(
            "LoadStep.mass_kg", self.mass_kg, MIN_LOAD_KG, "kg", "a 1 g weight is far below the rig's resolution"
        )
        if self.height_m is not None:
            validate.at_least("LoadStep.height_m", self.height_m, MIN_HEIGHT_M, "m", "0.1 mm above the pad")


@dataclass(frozen=True)
class Scenario:
    """A test: start height, load schedule, duration, and explicit rig overrides (dotted paths)."""

    name: str
    loads: tuple[LoadStep, ...]
    descent_height_m: float
    duration_s: float = 30.0  # Section 3.2: 30 s of simulated time
    overrides: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.loads, tuple) or not self.loads:
            raise ValueError(f"Scenario.loads must be a non-empty tuple of LoadStep, got {self.loads!r}")
        for load in self.loads:
            validate.instance("Scenario.loads item", load, LoadStep)
        validate.at_least("Scenario.descent_height_m", self.descent_height_m, MIN_HEIGHT_M, "m", "0.1 mm above the pad")
        validate.between("Scenario.duration_s", self.duration_s, MIN_DURATION_S, MAX_DURATION_S, "s")
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
        if not isinstance(self.overrides, Mapping):
            raise ValueError(f"Scenario.overrides must be a mapping of dotted parameter paths, got {self.overrides!r}")
        known = parameter_paths()
        for path in self.overrides:
            if path not in known:
                raise ValueError(f"Scenario.overrides: unknown parameter {path!r}")
        object.__setattr__(self, "overrides", dict(sorted(self.overrides.items())))

    def __hash__(self) -> int:
        return hash((self.name, self.loads, self.descent_height_m, self.duration_s, tuple(self.overrides.items())))

    @property
    def stages_kg(self) -> tuple[float, ...]:
        """Total external load of each stage, kg (the weights placed so far)."""
        return tuple(itertools.accumulate(load.mass_kg for load in self.loads))

    @property
    def loads_kg(self) -> tuple[float, ...]:
        return tuple(load.mass_kg for load in self.loads)

    @property
    def lowest_switch_height_m(self) -> float:
        """Height above which the start must stay so that only the t = 0 weights are on at the start."""
        heights = [load.height_m for load in self.loads if load.height_m is not None]
        return max(heights, default=0.0)

    def loads_due(self, height_m: float, placed: int) -> int:
        """How many weights are on the lander once its foot is at ``height_m``, ``placed`` being on."""
        while placed < len(self.loads):
            due = self.loads[placed].height_m
            if due is not None and height_m > due:
                break
            placed += 1
        return placed

    def rig_params(self, base: RigParams | None = None) -> RigParams:
        """``base`` (default: the paper's rig) with this scenario's explicit overrides, and nothing else."""
        base = RigParams() if base is None else base
        return with_overrides(base, self.overrides) if self.overrides else base

    def ideal_descent_m_s2(self, lander_mass_kg: float, gravity_m_s2: float) -> tuple[float, ...]:
        """Ideal descent acceleration of each load stage, m g / (M + m), signed up positive (Table 2)."""
        return tuple(-m * gravity_m_s2 / (lander_mass_kg + m) for m in self.stages_kg)

    def ideal_touchdown_s(self, lander_mass_kg: float, gravity_m_s2: float) -> float:
        """Time of the touchdown after the ideal free fall through the load stages, s."""
        starts = [self.descent_height_m if load.height_m is None else load.height_m for load in self.loads]
        time, speed = 0.0, 0.0
        for a, top, bottom in zip(
            self.ideal_descent_m_s2(lander_mass_kg, gravity_m_s2), starts, [*starts[1:], 0.0], strict=True
        ):
            drop = top - bottom  # fallen at -a from ``speed``: drop = speed t - a t^2 / 2
            duration = (-speed + math.sqrt(speed**2 - 2.0 * a * drop)) / -a
            time, speed = time + duration, speed - a * duration
        return time

    def impact_speed_m_s(self, lander_mass_kg: float, gravity_m_s2: float) -> float:
        """Speed at touchdown after the ideal free fall through the load stages."""
        starts = [self.descent_height_m if load.height_m is None else load.height_m for load in self.loads]
        heights = [*starts, 0.0]  # each stage falls from its start to the next one's (weights at t = 0: none)
        accelerations = self.ideal_descent_m_s2(lander_mass_kg, gravity_m_s2)
        energy = sum(
            -a * (top - bottom) for a, top, bottom in zip(accelerations, heights[:-1], heights[1:], strict=True)
        )
        return math.sqrt(2.0 * energy)


#: The paper's test conditions (Table 2; Section 3.2 for condition 3's second stage at 25 mm).
CONDITIONS: dict[int, Scenario] = {
    1: Scenario("condition 1", (LoadStep(0.49),), descent_height_m=0.09),
    2: Scenario("condition 2", (LoadStep(1.0),), descent_height_m=0.09),
    3: Scenario("condition 3", (LoadStep(0.05), LoadStep(1.0, height_m=0.025)), descent_height_m=0.055),
}


def condition(number: int) -> Scenario:
    """The paper's condition 1, 2 or 3."""
    return CONDITIONS[validate.integer("condition", number, 1, len(CONDITIONS))]
