"""One run, fully specified: :class:`RunSpec`, frozen, serialisable and content-hashed.

A spec names everything a run depends on: the test schedule, the rig's parameters by dotted path
(``servo.speed_loop_gain_hz``, ``qzs.guide_friction_n``), those in which the plant differs from the
rig its controller assumes, the imperfections switched off, the domain randomisation, the
controller (a name, a policy folder, or ``pid-retuned``: the PID re-tuned on this spec's rig and
period), its gains, the seed, the control period, the physics step and the
duration. Two specs with equal content have equal :attr:`RunSpec.hash`, on any machine and in any
process, so a campaign's stored results are keyed by it.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from microg_env import validate
from microg_env.controllers.pid import PIDGains, load_gains
from microg_env.controllers.registry import BASELINES, check_controller_name, controller_digest
from microg_env.imperfections import (
    IMPERFECTION_NAMES,
    PRESETS,
    DomainRandomization,
    Imperfections,
    apply_imperfections,
    check_parameters_used,
)
from microg_env.interface import SENSOR_SETS
from microg_env.params import (
    CONTROL_PERIOD_S,
    PHYSICS_STEP_S,
    RigParams,
    paper_rig,
    parameter_paths,
    typed_overrides,
    with_overrides,
)
from microg_env.scenarios import LoadStep, Scenario, comparison_scenarios
from microg_env.sim.model import EPISODE_PARAMETERS, check_physics_step, model_states
from microg_env.task import check_control_period
from microg_env.validate import shown

#: The controller that :mod:`microg_env.experiments.tuning` re-tunes on each spec's rig and period.
RETUNED_PID = "pid-retuned"
#: What ``RunSpec.randomize`` draws: nothing, the plant (lander, pad, friction, weights), the
#: plant and the drive, or both from ranges wider than training's.
RANDOMIZE = {False: None, True: DomainRandomization()} | {
    name: DomainRandomization.preset(name) for name in PRESETS if name != "plant"
}
#: Fields added after campaigns were first stored, with their defaults (left out of :meth:`RunSpec.as_dict`
#: at the default, so the content hash of every spec written before them is unchanged).
ADDED_FIELDS = {"sensor_set": "extended", "controller_digest": None, "plant_overrides": {}}
#: Characters of the SHA-256 content hash kept (64 bits: no collision in any campaign's lifetime).
HASH_CHARS = 16
#: The fields runs of one batch may differ in (the vector environment steps them together): who
#: drives and the seed, and the schedule, whose weights, start height and length are each rig's.
PER_RIG_FIELDS = (
    "controller",
    "controller_digest",
    "gains",
    "seed",
    "scenario",
    "loads",
    "descent_height_m",
    "duration_s",
)


@dataclass(frozen=True)
class RunSpec:
    """One run; see the module docstring. ``loads`` and ``descent_height_m`` replace the named
    scenario's schedule ((kg, switch height m or None) pairs; a custom schedule), ``duration_s`` its
    length; ``overrides`` are rig parameters by dotted path, the rig that runs and that its
    controller assumes; ``plant_overrides`` change the rig that runs alone: an unknown the
    controller does not know (it assumes ``overrides``; an oracle is told it, as it is told a drawn
    plant; one equal to the assumed rig's value is dropped); ``gains`` replace fields of the PID's
    tuned gains (``ki_per_s2``, ...); ``imperfections`` switches named imperfections (all on by
    default). ``controller_digest`` is not given but read: a policy's contents
    (:func:`~microg_env.controllers.registry.controller_digest`), None for a classical controller."""

    scenario: str = "condition-1"
    controller: str = "pid"
    seed: int = 0
    overrides: Mapping[str, Any] = field(default_factory=dict)
    gains: Mapping[str, float] = field(default_factory=dict)
    imperfections: Mapping[str, bool] = field(default_factory=dict)
    randomize: bool | str = False  # True: DomainRandomization(); "full"/"wider": DomainRandomization.full()/.wider()
    control_period_us: float = CONTROL_PERIOD_S * 1e6
    physics_step_us: float = PHYSICS_STEP_S * 1e6
    duration_s: float | None = None
    loads: tuple[tuple[float, float | None], ...] | None = None
    descent_height_m: float | None = None
    sensor_set: str = "extended"  # or "paper": no pad force sensor, no accelerometer
    plant_overrides: Mapping[str, Any] = field(default_factory=dict)
    controller_digest: str | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        known = comparison_scenarios()
        if self.scenario not in known:
            raise ValueError(f"RunSpec.scenario must be one of {', '.join(known)}, got {shown(self.scenario)}")
        validate.instance("RunSpec.controller", self.controller, str)
        validate.choice("RunSpec.sensor_set", self.sensor_set, tuple(SENSOR_SETS))
        set_ = object.__setattr__
        if self.controller != RETUNED_PID:
            check_controller_name(self.controller, self.sensor_set)
            set_(self, "controller_digest", controller_digest(self.controller))
        set_(self, "seed", validate.integer("RunSpec.seed", self.seed, 0, 2**32 - 1))
        if not isinstance(self.randomize, bool | str) or self.randomize not in RANDOMIZE:
            raise ValueError(
                f"RunSpec.randomize must be one of {', '.join(map(repr, RANDOMIZE))}, got {shown(self.randomize)}"
            )
        set_(self, "overrides", _overrides(self.overrides))
        set_(self, "plant_overrides", _overrides(self.plant_overrides, self.rig_params(), "RunSpec.plant_overrides"))
        set_(self, "gains", _named_floats("RunSpec.gains", self.gains, [f.name for f in fields(PIDGains)]))
        if self.gains and self.controller not in (*BASELINES, RETUNED_PID):
            raise ValueError(f"RunSpec.gains: controller {shown(self.controller)} has no PID gains to replace")
        if self.gains:  # the PID's own check, on the tuned gains these replace
            try:
                dataclasses.replace(load_gains("pid-dom" if self.controller == "pid-dom" else "pid"), **self.gains)
            except ValueError as error:
                raise ValueError(f"RunSpec.gains: {error}") from None
        set_(self, "imperfections", _named_flags(self.imperfections, list(IMPERFECTION_NAMES)))
        flags, sensors = self.imperfection_flags(), self.sensor_set
        check_parameters_used(self.rig_params(), flags, sensors, SENSOR_SETS[sensors], "RunSpec.overrides")
        check_parameters_used(self.plant_params(), flags, sensors, SENSOR_SETS[sensors], "RunSpec.plant_overrides")
        set_(self, "control_period_us", validate.positive("RunSpec.control_period_us", self.control_period_us, "us"))
        set_(self, "physics_step_us", validate.positive("RunSpec.physics_step_us", self.physics_step_us, "us"))
        check_control_period(self.control_period_s, check_physics_step(self.physics_step_s))
        if self.duration_s is not None:
            set_(self, "duration_s", validate.positive("RunSpec.duration_s", self.duration_s, "s"))
        if self.descent_height_m is not None:
            set_(self, "descent_height_m", validate.positive("RunSpec.descent_height_m", self.descent_height_m, "m"))
        if self.loads is not None:
            set_(self, "loads", _loads(self.loads))
        self.scenario_schedule()  # a bad schedule is named now, not in a worker

    # -- identity ----------------------------------------------------------------------------------

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready and complete: ``RunSpec.from_dict(spec.as_dict()) == spec``."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in ADDED_FIELDS:  # at its default, a field added later leaves older hashes as they were
            if out[name] == ADDED_FIELDS[name]:
                del out[name]
        out["loads"] = None if self.loads is None else [list(load) for load in self.loads]
        return (
            out
            | {"overrides": dict(self.overrides), "gains": dict(self.gains)}
            | {"imperfections": dict(self.imperfections)}
        )

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> RunSpec:
        """The spec of ``values`` (RunSpec field names; unknown names are refused). A
        ``controller_digest`` (as :meth:`as_dict` writes a policy's) must be the policy's now: a
        folder whose files changed since is refused, not run as the spec's."""
        validate.instance("run spec", values, Mapping)
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ValueError(f"unknown run spec field {shown(unknown[0])}; known: {', '.join(sorted(names))}")
        values = dict(values)
        recorded = values.pop("controller_digest", None)
        if values.get("loads") is not None:
            values["loads"] = tuple(tuple(load) if isinstance(load, list) else load for load in values["loads"])
        spec = cls(**values)
        if recorded is not None and recorded != spec.controller_digest:
            raise ValueError(
                f"RunSpec.controller_digest {shown(recorded)}: controller {shown(spec.controller)} now reads "
                f"{spec.controller_digest or 'as a classical controller'} (its files changed since the spec was "
                "written)"
            )
        return spec

    @property
    def hash(self) -> str:
        """The content hash: SHA-256 of the canonical JSON of :meth:`as_dict`, first 16 hex digits;
        a policy counts by its ``controller_digest``, not the path that names it (``polA``, ``./polA``
        and its absolute path are one controller)."""
        identity = self.as_dict()
        if self.controller_digest is not None:
            del identity["controller"]
        text = json.dumps(identity, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:HASH_CHARS]

    def __hash__(self) -> int:
        return hash(self.hash)

    @property
    def batch_key(self) -> str:
        """Equal for specs that run as rigs of one batch, on one compiled model: equal but in
        :data:`PER_RIG_FIELDS` and in the parameters an episode sets
        (:data:`~microg_env.sim.model.EPISODE_PARAMETERS`, which go with each rig's schedule)."""
        key = {k: v for k, v in self.as_dict().items() if k not in (*PER_RIG_FIELDS, "plant_overrides")}
        built = apply_imperfections(self.rig_schedule().rig_params(self.model_params()), self.imperfection_flags())
        paths = parameter_paths(built)
        key["overrides"] = {path: paths[path] for path in sorted(paths) if path not in EPISODE_PARAMETERS}
        key["model_states"] = model_states(built)  # an episode parameter's 0 removes a model state
        return json.dumps(key, sort_keys=True)

    @property
    def plant_key(self) -> str:
        """Equal for specs that differ only in who drives and the seed: one rig, schedule, period
        and randomisation (what ``pid-retuned`` is tuned on)."""
        return json.dumps(
            {k: v for k, v in self.as_dict().items() if k not in ("controller", "controller_digest", "gains", "seed")},
            sort_keys=True,
        )

    def replace(self, **changes: Any) -> RunSpec:
        return dataclasses.replace(self, **changes)

    # -- what it builds ----------------------------------------------------------------------------

    @property
    def control_period_s(self) -> float:
        return self.control_period_us / 1e6

    @property
    def physics_step_s(self) -> float:
        return self.physics_step_us / 1e6

    def scenario_schedule(self) -> Scenario:
        """The test schedule: the named scenario with this spec's loads, start height and duration."""
        scenario = comparison_scenarios()[self.scenario]
        changes: dict[str, Any] = {}
        if self.loads is not None:
            changes["loads"] = tuple(LoadStep(kg, height) for kg, height in self.loads)
        if self.descent_height_m is not None:
            changes["descent_height_m"] = self.descent_height_m
        if changes:
            changes["name"] = "custom"
        if self.duration_s is not None:
            changes["duration_s"] = self.duration_s
        return dataclasses.replace(scenario, **changes) if changes else scenario

    def rig_schedule(self) -> Scenario:
        """The schedule as one rig of a batch runs it: :meth:`scenario_schedule` carrying this spec's
        overrides (the plant's included) of the parameters an episode sets (the schedule's own take
        precedence, as in :meth:`env_kwargs`' environment)."""
        schedule = self.scenario_schedule()
        overrides = self._plant_overrides()
        mine = {path: value for path, value in overrides.items() if path in EPISODE_PARAMETERS}
        return dataclasses.replace(schedule, overrides=mine | dict(schedule.overrides)) if mine else schedule

    def rig_params(self) -> RigParams:
        """The nominal rig, as the controller assumes it: the paper's with this spec's overrides."""
        return with_overrides(paper_rig(), self.overrides)

    def plant_params(self) -> RigParams:
        """The rig that runs: :meth:`rig_params` with this spec's plant overrides."""
        return with_overrides(paper_rig(), self._plant_overrides())

    def _plant_overrides(self) -> dict[str, Any]:
        return dict(self.overrides) | dict(self.plant_overrides)

    def model_params(self) -> RigParams:
        """The rig of a batch's compiled model: the paper's with this spec's overrides (the plant's
        included) but those of the parameters an episode sets (:meth:`rig_schedule` carries them)."""
        overrides = self._plant_overrides()
        return with_overrides(paper_rig(), {p: v for p, v in overrides.items() if p not in EPISODE_PARAMETERS})

    def imperfection_flags(self) -> Imperfections:
        return Imperfections(**self.imperfections)

    def env_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of ``MicroGravityLandingEnv`` (and the batch's core) for this spec."""
        return {
            "scenario": self.scenario_schedule(),
            "control_period_s": self.control_period_s,
            "physics_step_s": self.physics_step_s,
            "imperfections": self.imperfection_flags(),
            "domain_randomization": RANDOMIZE[self.randomize],
            "sensor_set": self.sensor_set,
            "params": self.plant_params(),
        }

    def batch_kwargs(self) -> dict[str, Any]:
        """The batch core's settings for this spec's batch: :meth:`env_kwargs` with the
        :meth:`model_params` and no schedule (each rig has its :meth:`rig_schedule`)."""
        kwargs = self.env_kwargs() | {"params": self.model_params()}
        del kwargs["scenario"]
        return kwargs


def _overrides(values: object, base: RigParams | None = None, name: str = "RunSpec.overrides") -> dict[str, Any]:
    """Dotted rig parameters, each value of its default's type (so 100 and 100.0 hash alike); a
    value equal to ``base``'s (default: the paper's rig) is dropped (the same run hashes alike
    however it is written)."""
    defaults = parameter_paths(base)
    base = paper_rig() if base is None else base
    typed = typed_overrides(name, values)
    out = {path: value for path, value in sorted(typed.items()) if value != defaults[path]}
    with_overrides(base, out)  # the parameters' own checks name a bad value now
    return out


def _named_floats(name: str, values: object, known: list[str]) -> dict[str, float]:
    validate.instance(name, values, Mapping)
    out = {}
    for key, value in sorted(values.items()):
        if key not in known:
            raise ValueError(f"{name}: unknown field {shown(key)}; known: {', '.join(known)}")
        out[key] = validate.finite(f"{name}.{key}", value)
    return out


def _named_flags(values: object, known: list[str]) -> dict[str, bool]:
    validate.instance("RunSpec.imperfections", values, Mapping)
    out = {}
    for key, value in sorted(values.items()):
        if key not in known:
            raise ValueError(f"RunSpec.imperfections: unknown imperfection {shown(key)}; known: {', '.join(known)}")
        if not validate.instance(f"RunSpec.imperfections.{key}", value, bool):  # on is the default
            out[key] = False
    return out


def _loads(values: object) -> tuple[tuple[float, float | None], ...]:
    if not isinstance(values, tuple | list) or not values:
        raise ValueError(f"RunSpec.loads must be a non-empty list of (kg, height m or None), got {shown(values)}")
    out = []
    for load in values:
        if not isinstance(load, tuple | list) or len(load) != 2:
            raise ValueError(f"RunSpec.loads item must be (kg, height m or None), got {shown(load)}")
        mass = validate.finite("RunSpec.loads kg", load[0])
        height = None if load[1] is None else validate.finite("RunSpec.loads height", load[1])
        out.append((mass, height))
    return tuple(out)


#: The RunSpec fields that map names to values: a campaign key reaches an entry as FIELD.NAME.
NESTED_FIELDS = ("overrides", "plant_overrides", "gains", "imperfections")


@functools.cache
def _plain_fields() -> frozenset[str]:
    """The RunSpec fields a campaign key sets whole (seeds come from ``seeds:``)."""
    return frozenset(f.name for f in fields(RunSpec) if f.init) - {*NESTED_FIELDS, "seed"}


@functools.cache
def _rig_parameters() -> frozenset[str]:
    return frozenset(parameter_paths())


def spec_entry(key: str) -> tuple[str, ...]:
    """Where the campaign key ``key`` lands in a RunSpec: ``(field,)``, or ``(field, name)`` in one
    of :data:`NESTED_FIELDS`; a rig parameter's dotted path lands in overrides, so
    ``pad.stiffness_n_per_m`` and ``overrides.pad.stiffness_n_per_m`` land alike."""
    part, _, rest = key.partition(".")
    if key in _plain_fields():
        return (key,)
    if part in NESTED_FIELDS and rest:
        return (part, rest)
    if key in _rig_parameters():
        return ("overrides", key)
    raise ValueError(
        f"{shown(key)} is neither a run spec field, gains.NAME, imperfections.NAME, plant_overrides.NAME nor a "
        "rig parameter (dotted path, e.g. qzs.guide_friction_n)"
    )
