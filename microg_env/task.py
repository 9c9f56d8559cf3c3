"""The landing task's settings: one frozen record, checked once, owned here.

:class:`TaskSettings` holds every keyword argument of ``MicroGravityLanding-v1`` but rendering
(the class docstring of :class:`~microg_env.envs.landing.MicroGravityLandingEnv` says what each
means), with its default; both environments take them as keyword arguments and pass them through
to :class:`~microg_env.envs.core.LandingCore`. Times are seconds and lengths metres.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from microg_env import validate
from microg_env.imperfections import DomainRandomization, Imperfections, check_parameters_used
from microg_env.interface import (
    ACTION_MODES,
    BASELINES,
    DESCENT_SCALE_M_S,
    GAIN_BASES,
    GAIN_LIMIT,
    MAX_GAIN_LIMIT,
    MAX_SPEED_M_S,
    MIXED_SENSORS,
    RESIDUAL_HIGHPASS_RANGE_HZ,
    RESIDUAL_LIMIT_M,
    SENSOR_SETS,
    SPEED_LIMIT_RANGE_M_S,
    hidden_entries,
    highpass_order,
    residual_gate,
    residual_gate_point,
)
from microg_env.params import (
    CONTROL_PERIOD_RANGE_S,
    CONTROL_PERIOD_S,
    PHYSICS_STEP_S,
    RigParams,
    typed_overrides,
    with_overrides,
)
from microg_env.scenarios import Scenario, ScenarioSampler
from microg_env.scenarios import condition as paper_condition
from microg_env.sim.model import DEFAULT_DRIVE_SCHEME, DRIVE_SCHEMES, check_physics_step
from microg_env.validate import FieldError


@dataclass(frozen=True)
class ActingSettings:
    """How a policy acts on the rig, one record checked once when made: what its action means (the
    drive's speed command up to ``speed_limit_m_s``, a setpoint for x that a classical
    ``base_controller`` holds, scaled to ``residual_limit_m``, or multipliers of a base PID's gains
    up to ``gain_limit``), how often it acts (every ``decision_period`` control periods), how the
    residual is high-passed (a corner and one or two stages) and gated (acting only while the foot
    reads at most ``residual_gate_m`` high, the gate on the action or the setpoint), and the
    observation entries it reads as 0. The environment (:class:`TaskSettings`), the policy loader
    and the policy cards read it; its fields are the cards' :data:`ACTING_KEYS`."""

    action_mode: str = "speed"
    base_controller: str = "pid"
    decision_period: int = 1
    residual_limit_m: float = RESIDUAL_LIMIT_M
    residual_highpass_hz: float = 0.0
    residual_highpass_order: int = 1
    residual_gate_m: float | None = None
    residual_gate_on: str = "action"
    gain_limit: float = GAIN_LIMIT
    speed_limit_m_s: float = MAX_SPEED_M_S
    hidden_observations: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        put("hidden_observations", hidden_entries(self.hidden_observations))
        put("decision_period", validate.integer("decision_period", self.decision_period, 1, 1000))
        validate.choice("action_mode", self.action_mode, ACTION_MODES)
        validate.choice("base_controller", self.base_controller, BASELINES)
        put("residual_limit_m", validate.positive("residual_limit_m", self.residual_limit_m, "m", 1e-3))
        corner = validate.between("residual_highpass_hz", self.residual_highpass_hz, *RESIDUAL_HIGHPASS_RANGE_HZ, "Hz")
        put("residual_highpass_hz", corner)
        put("residual_highpass_order", highpass_order(self.residual_highpass_order))
        put("residual_gate_m", residual_gate(self.residual_gate_m))
        put("residual_gate_on", residual_gate_point(self.residual_gate_on))
        if self.residual_gate_on != "action" and self.residual_gate_m is None:
            raise FieldError(
                f"residual_gate_on {self.residual_gate_on!r}: there is no gate to place (residual_gate_m is None)",
                "residual_gate_on",
            )
        put("gain_limit", validate.between("gain_limit", self.gain_limit, 1.0, MAX_GAIN_LIMIT))
        if self.gain_limit == 1.0:
            raise FieldError("gain_limit 1.0: the action would move no gain (it must be above 1)", "gain_limit")
        put("speed_limit_m_s", validate.between("speed_limit_m_s", self.speed_limit_m_s, *SPEED_LIMIT_RANGE_M_S, "m/s"))
        if self.action_mode == "gains" and self.base_controller not in GAIN_BASES:
            raise FieldError(
                f"base_controller {self.base_controller!r}: action_mode='gains' schedules the gains of "
                f"{' or '.join(GAIN_BASES)}",
                "base_controller",
            )
        for option in fields(ActingSettings):  # the options of the other action modes keep their defaults
            mode = _OPTION_MODES.get(option.name)
            if mode is not None and self.action_mode not in mode and getattr(self, option.name) != option.default:
                raise FieldError(
                    f"{option.name} {getattr(self, option.name)!r}: only action_mode {' or '.join(map(repr, mode))} "
                    f"has it (action_mode is {self.action_mode!r})",
                    option.name,
                )
        if self.residual_highpass_order != 1 and self.residual_highpass_hz == 0.0:
            raise FieldError(
                f"residual_highpass_order {self.residual_highpass_order!r}: there is no high-pass to cascade "
                "(residual_highpass_hz is 0)",
                "residual_highpass_order",
            )

    @classmethod
    def of(cls, settings: Mapping[str, Any]) -> ActingSettings:
        """The acting settings among ``settings`` (a card's env_kwargs, a task's keywords), those left
        out at their defaults; the other keys are not read."""
        return cls(**{name: settings[name] for name in ACTING_KEYS if name in settings})


#: The action modes that read each option of :class:`ActingSettings` (the options not named read by every mode).
_OPTION_MODES = {
    "base_controller": ("residual", "gains"),
    "gain_limit": ("gains",),
    "speed_limit_m_s": ("speed",),
    **{option.name: ("residual",) for option in fields(ActingSettings) if option.name.startswith("residual_")},
    "residual_gate_m": ("residual", "gains"),  # a gains action is gated as a residual is
}
#: The settings that say how a policy acts: :class:`ActingSettings`' fields.
ACTING_KEYS = tuple(option.name for option in fields(ActingSettings))


@dataclass(frozen=True)
class TaskSettings(ActingSettings):
    """The task's settings, checked and normalised when made (how a policy acts, the
    :class:`ActingSettings` it extends, among them): ``scenario_sampler``,
    ``imperfections`` and ``domain_randomization`` become their records (a name, a mapping or
    True as the environment's keywords accept), ``params`` a :class:`RigParams` (given as one, or as
    overrides of the paper's rig by dotted path, as a rig file holds them); an invalid value raises
    a :class:`~microg_env.validate.FieldError` naming it."""

    condition: int = 1
    scenario: Scenario | None = None
    scenario_sampler: ScenarioSampler | str | Mapping | None = None
    control_period_s: float = CONTROL_PERIOD_S
    physics_step_s: float = PHYSICS_STEP_S
    drive_scheme: str = DEFAULT_DRIVE_SCHEME
    imperfections: Imperfections | Mapping | None = None
    domain_randomization: DomainRandomization | Mapping | bool | str | None = None
    sensor_set: str = "extended"
    params: RigParams | Mapping | None = None
    xml_file: str | None = None
    reward_scale_m: float = 1e-8
    reward_descent_weight: float = 0.0
    reward_descent_scale_m_s: float = DESCENT_SCALE_M_S
    reset_noise_scale: float = 0.0

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        put("scenario_sampler", _sampler(self.scenario_sampler))
        if self.scenario_sampler is not None and self.scenario is not None:
            raise ValueError("give scenario (or scenarios) or scenario_sampler, not both")
        if self.condition != 1 and (self.scenario is not None or self.scenario_sampler is not None):
            given = "scenario" if self.scenario is not None else "scenario_sampler"
            raise FieldError(f"condition {self.condition!r}: {given} gives the schedule; give one of them", "condition")
        if self.scenario is None:
            paper_condition(self.condition)  # a condition of the paper's, or an error naming it
        else:
            validate.instance("scenario", self.scenario, Scenario)
        put("imperfections", _imperfections(self.imperfections))
        put("domain_randomization", _randomization(self.domain_randomization))
        validate.choice("sensor_set", self.sensor_set, (*SENSOR_SETS, MIXED_SENSORS))
        if isinstance(self.params, Mapping):  # overrides by dotted path (a hyperparameter file's, a card's)
            put("params", with_overrides(RigParams(), typed_overrides("params", self.params)))
        put("params", RigParams() if self.params is None else self.params)
        validate.instance("params", self.params, RigParams)
        missing = SENSOR_SETS.get(self.sensor_set, ())  # mixed: each episode draws a set
        check_parameters_used(self.params, self.imperfections, self.sensor_set, missing, "params")
        put("physics_step_s", check_physics_step(self.physics_step_s))
        put("control_period_s", check_control_period(self.control_period_s, self.physics_step_s))
        validate.choice("drive_scheme", self.drive_scheme, DRIVE_SCHEMES)
        super().__post_init__()  # how a policy acts
        put("reward_scale_m", validate.between("reward_scale_m", self.reward_scale_m, 1e-12, 1e-3, "m"))
        put("reward_descent_weight", validate.between("reward_descent_weight", self.reward_descent_weight, 0.0, 1.0))
        scale = validate.between("reward_descent_scale_m_s", self.reward_descent_scale_m_s, 1e-12, 1e-3, "m/s")
        put("reward_descent_scale_m_s", scale)
        if self.reward_descent_weight == 0.0 and scale != DESCENT_SCALE_M_S:
            raise FieldError(
                f"reward_descent_scale_m_s {scale!r}: the descent term it scales has no weight "
                "(reward_descent_weight is 0)",
                "reward_descent_scale_m_s",
            )
        put("reset_noise_scale", validate.non_negative("reset_noise_scale", self.reset_noise_scale, "m"))
        if self.scenario_sampler is not None and self.reset_noise_scale > 0:
            raise FieldError(
                f"reset_noise_scale {self.reset_noise_scale!r} m: a scenario_sampler draws the start height itself "
                "(its descent_height_m range); give one or the other",
                "reset_noise_scale",
            )
        if self.xml_file is not None:
            path = Path(str(self.xml_file))
            if path.suffix.lower() != ".xml" or not path.is_file():
                raise FieldError(f"xml_file {str(self.xml_file)!r} is not an .xml file", "xml_file")
            put("xml_file", str(self.xml_file))

    @property
    def acting(self) -> ActingSettings:
        """How a policy acts in this task: its :class:`ActingSettings` alone (checked when this was made)."""
        return ActingSettings.of({name: getattr(self, name) for name in ACTING_KEYS})

    @property
    def schedule(self) -> Scenario:
        """The fixed schedule: ``scenario``, else the paper's ``condition`` (a sampler draws its own)."""
        return paper_condition(self.condition) if self.scenario is None else self.scenario

    @property
    def frame_skip(self) -> int:
        """Physics steps per control period."""
        return round(self.control_period_s / self.physics_step_s)


def _sampler(value: ScenarioSampler | str | Mapping | None) -> ScenarioSampler | None:
    if value is None or isinstance(value, ScenarioSampler):
        return value
    if value == "training":
        return ScenarioSampler()
    if isinstance(value, Mapping):
        return ScenarioSampler(**{k: tuple(v) if isinstance(v, list) else v for k, v in value.items()})
    raise ValueError(f"scenario_sampler must be a ScenarioSampler, 'training' or a dict, got {value!r}")


def _imperfections(value: Imperfections | Mapping | None) -> Imperfections:
    if value is None:
        return Imperfections()
    if isinstance(value, Mapping):
        return Imperfections(**value)
    return validate.instance("imperfections", value, Imperfections)


def _randomization(value: DomainRandomization | Mapping | bool | str | None) -> DomainRandomization | None:
    if value is None or value is False:
        return None
    if value is True:
        return DomainRandomization()
    if isinstance(value, str):  # a preset by name (a YAML file can name it)
        return DomainRandomization.preset(value)
    if isinstance(value, Mapping):
        return DomainRandomization(**value)
    return validate.instance("domain_randomization", value, DomainRandomization)


def check_control_period(control_period_s: float, physics_step_s: float) -> float:
    """``control_period_s`` if the RTX timer offers it and it is a whole number of physics steps."""
    low, high = CONTROL_PERIOD_RANGE_S
    period = validate.positive("control_period_s", control_period_s, "s")
    if not low - 1e-12 <= period <= high + 1e-12:
        raise FieldError(
            f"control_period_s must be in [{low:g}, {high:g}] s (the RTX timer's 100 us to 10 ms), "
            f"got {control_period_s!r}",
            "control_period_s",
        )
    steps = period / physics_step_s
    if abs(steps - round(steps)) > 1e-6 * steps:
        raise FieldError(
            f"control_period_s {control_period_s!r} s must be a whole number of physics steps of {physics_step_s:g} s",
            "control_period_s",
            "physics_step_s",
        )
    return period
