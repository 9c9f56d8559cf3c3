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
from dataclasses import dataclass, field, replace

from microg_env import validate
from microg_env.params import RigParams, parameter_paths, with_overrides
from microg_env.validate import FieldError

#: Shortest and longest test a scenario may schedule, s.
MIN_DURATION_S, MAX_DURATION_S = 0.01, 600.0
#: Lowest start or switch height, m: a foot 0.1 mm above the pad is as good as on it.
MIN_HEIGHT_M = 1.0e-4
#: Time after a weight is placed before its stage's descent counts, s: fitted (the compensation
#: error, analysis.metrics) and scored (the reward's descent term, envs.period.score_descent). The
#: PID loop settles in ~0.1 s (closed-loop pair at ~140 rad/s, damping ~0.7).
SETTLE_S = 0.2
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
            raise FieldError(
                f"Scenario.loads must be a non-empty tuple of LoadStep, got {self.loads!r}", "Scenario.loads"
            )
        for load in self.loads:
            validate.instance("Scenario.loads item", load, LoadStep)
        validate.at_least("Scenario.descent_height_m", self.descent_height_m, MIN_HEIGHT_M, "m", "0.1 mm above the pad")
        validate.between("Scenario.duration_s", self.duration_s, MIN_DURATION_S, MAX_DURATION_S, "s")
        heights = [math.inf if load.height_m is None else load.height_m for load in self.loads]
        if heights != sorted(heights, reverse=True):
            raise FieldError(
                "Scenario.loads must be in the order they are placed: t = 0 first, then by falling height",
                "Scenario.loads",
            )
        for load in self.loads:
            if load.height_m is not None and load.height_m >= self.descent_height_m:
                raise FieldError(
                    f"Scenario.loads height {load.height_m!r} m must be below the descent height "
                    f"{self.descent_height_m!r} m (use None to place a weight at t = 0)",
                    "Scenario.loads",
                    "Scenario.descent_height_m",
                )
        if self.loads[0].height_m is not None:
            raise FieldError("Scenario.loads: the first weight must be placed at t = 0 (height None)", "Scenario.loads")
        if not isinstance(self.overrides, Mapping):
            raise FieldError(
                f"Scenario.overrides must be a mapping of dotted parameter paths, got {self.overrides!r}",
                "Scenario.overrides",
            )
        known = parameter_paths()
        for path in self.overrides:
            if path not in known:
                raise FieldError(f"Scenario.overrides: unknown parameter {path!r}", "Scenario.overrides")
        object.__setattr__(self, "overrides", dict(sorted(self.overrides.items())))

    def __hash__(self) -> int:
        return hash((self.name, self.loads, self.descent_height_m, self.duration_s, tuple(self.overrides.items())))

    @property
    def loads_text(self) -> str:
        """The schedule's weights in words: ``0.05 kg, 1 kg at 25 mm``."""
        return ", ".join(
            f"{load.mass_kg:g} kg" + ("" if load.height_m is None else f" at {load.height_m * 1e3:g} mm")
            for load in self.loads
        )

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
        """Ideal descent acceleration of each load stage (:func:`ideal_descent_m_s2`)."""
        return tuple(ideal_descent_m_s2(m, lander_mass_kg, gravity_m_s2) for m in self.stages_kg)

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


def ideal_descent_m_s2(load_kg: float, lander_mass_kg: float, gravity_m_s2: float) -> float:
    """Ideal descent acceleration with ``load_kg`` placed, m g / (M + m), signed up positive (Table 2)."""
    return -load_kg * gravity_m_s2 / (lander_mass_kg + load_kg)


#: The paper's test conditions (Table 2; Section 3.2 for condition 3's second stage at 25 mm).
CONDITIONS: dict[int, Scenario] = {
    1: Scenario("condition 1", (LoadStep(0.49),), descent_height_m=0.09),
    2: Scenario("condition 2", (LoadStep(1.0),), descent_height_m=0.09),
    3: Scenario("condition 3", (LoadStep(0.05), LoadStep(1.0, height_m=0.025)), descent_height_m=0.055),
}


def condition(number: int) -> Scenario:
    """The paper's condition 1, 2 or 3."""
    return CONDITIONS[validate.integer("condition", number, 1, len(CONDITIONS))]


@dataclass(frozen=True)
class ScenarioSampler:
    """Training schedules, drawn at every reset: short episodes that still hold a load placement
    and a touchdown.

    Two test weights: the first, ``first_load_kg``, placed at t = 0, the second, ``second_load_kg``,
    when the foot comes down to a fraction ``switch_fraction`` of the start height; the start height
    is drawn in ``descent_height_m`` until the ideal free fall touches down within
    ``max_touchdown_s``, and the episode lasts ``after_touchdown_s`` beyond the touchdown (the first
    contact, ~1.2 s on the paper's pad, and the start of the rebound). The paper's conditions start
    higher (55-90 mm): they stay held out of training.
    """

    first_load_kg: tuple[float, float] = (0.05, 1.0)
    second_load_kg: tuple[float, float] = (0.05, 1.0)
    descent_height_m: tuple[float, float] = (0.003, 0.03)
    switch_fraction: tuple[float, float] = (0.2, 0.8)
    max_touchdown_s: float = 3.0
    after_touchdown_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("first_load_kg", "second_load_kg", "descent_height_m", "switch_fraction"):
            low, high = _range(f"ScenarioSampler.{name}", getattr(self, name))
            if name.endswith("_kg"):
                validate.at_least(f"ScenarioSampler.{name}", low, MIN_LOAD_KG, "kg")
            elif name == "descent_height_m":
                validate.at_least(f"ScenarioSampler.{name}", low, 2 * MIN_HEIGHT_M, "m")
            else:
                validate.between(f"ScenarioSampler.{name}", low, 0.01, 0.99)
                validate.between(f"ScenarioSampler.{name}", high, 0.01, 0.99)
        validate.positive("ScenarioSampler.max_touchdown_s", self.max_touchdown_s, "s", 60.0)
        validate.positive("ScenarioSampler.after_touchdown_s", self.after_touchdown_s, "s", 60.0)

    def sample(self, rng, lander_mass_kg: float, gravity_m_s2: float) -> Scenario:
        """A schedule whose ideal free fall touches down within ``max_touchdown_s``."""
        first, second = rng.uniform(*self.first_load_kg), rng.uniform(*self.second_load_kg)
        fraction = rng.uniform(*self.switch_fraction)
        low, high = self.descent_height_m
        while True:  # the lowest start always touches down in time (checked by ``extremes``)
            height = rng.uniform(low, high)
            scenario = self._schedule(first, second, height, fraction)
            touchdown = scenario.ideal_touchdown_s(lander_mass_kg, gravity_m_s2)
            if touchdown <= self.max_touchdown_s:
                return replace(scenario, duration_s=touchdown + self.after_touchdown_s)
            high = height  # shrink towards the low end

    def _schedule(self, first: float, second: float, height: float, fraction: float) -> Scenario:
        loads = (LoadStep(first), LoadStep(second, height_m=max(fraction * height, MIN_HEIGHT_M)))
        return Scenario("training", loads, descent_height_m=height)

    def extremes(self, lander_mass_kg: float, gravity_m_s2: float) -> tuple[Scenario, ...]:
        """The draws every check must pass: the heaviest weights from the highest start, and the
        lightest from the lowest (the longest fall), which must touch down in time."""
        heavy = self._schedule(self.first_load_kg[1], self.second_load_kg[1], self.descent_height_m[1], 0.99)
        light = self._schedule(self.first_load_kg[0], self.second_load_kg[0], self.descent_height_m[0], 0.01)
        longest = light.ideal_touchdown_s(lander_mass_kg, gravity_m_s2)
        if longest > self.max_touchdown_s:
            raise FieldError(
                f"ScenarioSampler.descent_height_m {self.descent_height_m!r}: its lightest draw from its lowest start "
                f"touches down after {longest:.2f} s, beyond max_touchdown_s {self.max_touchdown_s:g} s",
                "ScenarioSampler.descent_height_m",
            )
        return heavy, replace(light, duration_s=longest + self.after_touchdown_s)

    def outside(
        self, scenario: Scenario, lander_mass_kg: float, gravity_m_s2: float, load_spread: float = 0.0
    ) -> tuple[str, ...]:
        """How ``scenario`` lies outside every schedule this sampler draws: "impact speed" (faster
        than its fastest draw), "load" (a weight outside its ranges, each widened by the domain
        randomisation's relative ``load_spread``), "start height" (outside its starts) and "stages"
        (other than its two weights). Empty: a schedule it could draw."""
        # the fastest draw: the heaviest weights from the highest start, the second placed earliest
        heavy = self._schedule(
            self.first_load_kg[1], self.second_load_kg[1], self.descent_height_m[1], self.switch_fraction[1]
        )
        fastest = heavy.impact_speed_m_s(lander_mass_kg, gravity_m_s2) * math.sqrt(1.0 + load_spread)
        low = min(self.first_load_kg[0], self.second_load_kg[0]) * (1.0 - load_spread)
        high = max(self.first_load_kg[1], self.second_load_kg[1]) * (1.0 + load_spread)
        found = {
            "impact speed": scenario.impact_speed_m_s(lander_mass_kg, gravity_m_s2) > fastest,
            "load": any(not low <= load <= high for load in scenario.loads_kg),
            "start height": not self.descent_height_m[0] <= scenario.descent_height_m <= self.descent_height_m[1],
            "stages": len(scenario.loads) != 2,
        }
        return tuple(name for name, out in found.items() if out)


def _range(name: str, pair: object) -> tuple[float, float]:
    if not (isinstance(pair, tuple) and len(pair) == 2):
        raise FieldError(f"{name} must be a (low, high) pair, got {pair!r}", name)
    low, high = (validate.positive(name, value) for value in pair)
    if low > high:
        raise FieldError(f"{name} must be a (low, high) pair with low <= high, got {pair!r}", name)
    return low, high


#: Schedules that choose the best model during training: starts of 30-50 mm, between the training
#: draws (3-30 mm) and the paper's conditions (55-90 mm), so the first weight's free fall lasts
#: the second a compensation error needs.
VALIDATION_SAMPLER = ScenarioSampler(
    first_load_kg=(0.1, 1.0), descent_height_m=(0.03, 0.05), switch_fraction=(0.2, 0.4), max_touchdown_s=8.0
)


#: Test schedules held out of training and validation, beside the paper's conditions; each lies
#: outside both samplers' draws in its start height and at least one of impact speed, load and
#: number of weights (``ScenarioSampler.outside``, pinned by a test). Together they span impacts of
#: 17-65 mm/s (training draws at most 48 mm/s), weights of 0.1-2 kg (training: 0.05-1 kg), starts
#: of 55-120 mm (training 3-30 mm, validation 30-50 mm) and one to four weights (training: two):
#: a second weight heavier than any drawn, a light weight with a long free fall, a fast impact, three
#: weights, the heaviest single weight, four weights, the highest start, and a heavy first weight.
HELD_OUT: dict[str, Scenario] = {
    "heavy-second": Scenario(
        "heavy-second", (LoadStep(0.3), LoadStep(1.4, height_m=0.02)), descent_height_m=0.07, duration_s=10.0
    ),
    "light-long": Scenario("light-long", (LoadStep(0.15),), descent_height_m=0.06, duration_s=12.0),
    "fast-impact": Scenario("fast-impact", (LoadStep(1.5),), descent_height_m=0.09, duration_s=6.0),
    "three-stage": Scenario(
        "three-stage",
        (LoadStep(0.1), LoadStep(0.6, height_m=0.04), LoadStep(1.2, height_m=0.015)),
        descent_height_m=0.06,
        duration_s=10.0,
    ),
    "heavy-single": Scenario("heavy-single", (LoadStep(2.0),), descent_height_m=0.055, duration_s=5.0),
    "four-stage": Scenario(
        "four-stage",
        (LoadStep(0.2), LoadStep(0.3, height_m=0.05), LoadStep(0.4, height_m=0.03), LoadStep(0.5, height_m=0.012)),
        descent_height_m=0.08,
        duration_s=9.0,
    ),
    "high-start": Scenario(
        "high-start", (LoadStep(0.7), LoadStep(0.5, height_m=0.03)), descent_height_m=0.12, duration_s=7.0
    ),
    "heavy-first": Scenario(
        "heavy-first", (LoadStep(1.3), LoadStep(0.1, height_m=0.03)), descent_height_m=0.065, duration_s=5.0
    ),
}


def comparison_scenarios() -> dict[str, Scenario]:
    """The scenarios of a comparison by name: ``condition-1`` to ``condition-3`` and :data:`HELD_OUT`."""
    return {f"condition-{number}": scenario for number, scenario in CONDITIONS.items()} | HELD_OUT
