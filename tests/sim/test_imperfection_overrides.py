"""A rig parameter set where an imperfection that is off (or the sensor set) leaves it without effect
is refused, in a RunSpec (campaigns, compare) and in ``gym.make``, not run and tabled as if it mattered."""

from __future__ import annotations

import math
from dataclasses import replace

import gymnasium as gym
import pytest

import microg_env  # noqa: F401  (registers the environments)
from microg_env.experiments.campaign import Campaign
from microg_env.imperfections import (
    IMPERFECTION_NAMES,
    READ_ONLY_BY_ENTRY,
    READ_ONLY_WHEN_ON,
    Imperfections,
    apply_imperfections,
)
from microg_env.interface import OBSERVATION_INDEX, SENSOR_SETS
from microg_env.params import RigParams, parameter_paths, with_overrides
from microg_env.rollout.spec import RunSpec
from microg_env.task import TaskSettings
from microg_env.validate import FieldError

DEFAULTS = parameter_paths()


def _off(name: str) -> Imperfections:
    return replace(Imperfections(), **{name: False})


def _unused(name: str) -> list[str]:
    """The parameters imperfection ``name`` switched off leaves without effect: those
    :func:`apply_imperfections` overwrites on the paper's rig, and its part the environment reads
    only while it is on."""
    applied = parameter_paths(apply_imperfections(RigParams(), _off(name)))
    part = READ_ONLY_WHEN_ON.get(name)
    return [path for path in DEFAULTS if applied[path] != DEFAULTS[path] or path.partition(".")[0] == part]


#: (imperfection, parameter) for every parameter some imperfection switched off leaves unused.
UNUSED = [(name, path) for name in IMPERFECTION_NAMES for path in _unused(name)]
#: The parameters a sensor set leaves unread, as (sensor set, parameter).
UNREAD = [
    (sensor_set, path)
    for sensor_set, missing in SENSOR_SETS.items()
    for entry in missing
    for path in READ_ONLY_BY_ENTRY.get(entry, ())
]


def _changed(path: str) -> object:
    """A valid value of ``path`` that is neither its default nor what an imperfection sets it to."""
    default = DEFAULTS[path]
    return type(default)(default * 0.9) if default else 1e-6


def _refused(error: pytest.ExceptionInfo, source: str, path: str, value: object, cause: str) -> None:
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(f"{source} {path} = {value!r}: {cause}"), message
    assert error.value.fields[0] == path


def test_the_table_holds_the_parameters_the_review_found_without_effect():
    """The derivation finds what the review measured bit-identical: the guide's friction with the
    friction off, the cogging torque with cogging off, the peak torque with the torque limit off;
    and the tables of parts and readings name real imperfections, parts, readings and parameters."""
    assert {("friction", "qzs.guide_friction_n"), ("cogging", "servo.cogging_torque_n_m")} <= set(UNUSED)
    assert ("torque_limit", "servo.peak_torque_n_m") in UNUSED
    assert set(READ_ONLY_WHEN_ON) <= set(IMPERFECTION_NAMES)
    assert {path.partition(".")[0] for path in DEFAULTS} >= set(READ_ONLY_WHEN_ON.values())
    assert set(READ_ONLY_BY_ENTRY) <= set(OBSERVATION_INDEX)
    assert all(path in DEFAULTS for paths in READ_ONLY_BY_ENTRY.values() for path in paths)
    assert UNREAD


@pytest.mark.parametrize(("name", "path"), UNUSED)
def test_a_run_spec_refuses_a_parameter_its_imperfection_off_leaves_unused(name, path):
    value = _changed(path)
    with pytest.raises(FieldError) as refused:
        RunSpec(scenario="condition-2", imperfections={name: False}, overrides={path: value})
    _refused(refused, "RunSpec.overrides", path, value, f"imperfection {name!r} is off")


@pytest.mark.parametrize(("name", "path"), UNUSED)
def test_gym_make_refuses_a_parameter_its_imperfection_off_leaves_unused(name, path):
    value = _changed(path)
    params = with_overrides(RigParams(), {path: value})
    with pytest.raises(FieldError) as refused:
        gym.make("MicroGravityLanding-v1", imperfections={name: False}, params=params)
    _refused(refused, "params", path, value, f"imperfection {name!r} is off")


@pytest.mark.parametrize("name", IMPERFECTION_NAMES)
def test_each_imperfection_off_still_takes_the_defaults_and_the_parameters_it_does_not_touch(name):
    """The normal case: the imperfection overwrites a parameter left at its default. A parameter
    only another imperfection leaves unused, and one set to what this one sets it to, are taken."""
    mine = set(_unused(name))
    others = {path: _changed(path) for other, path in UNUSED if path not in mine}
    RunSpec(scenario="condition-2", imperfections={name: False}, overrides=others)
    TaskSettings(imperfections={name: False}, params=with_overrides(RigParams(), others))
    TaskSettings(imperfections=_off(name), params=apply_imperfections(RigParams(), _off(name)))
    gym.make("MicroGravityLanding-v1", imperfections={name: False}).close()


def test_every_imperfection_off_takes_the_paper_rig():
    RunSpec(imperfections=dict.fromkeys(IMPERFECTION_NAMES, False))
    TaskSettings(imperfections=Imperfections.none(), params=apply_imperfections(RigParams(), Imperfections.none()))


@pytest.mark.parametrize(("sensor_set", "path"), UNREAD)
def test_a_sensor_set_refuses_the_parameter_of_a_reading_it_lacks(sensor_set, path):
    """``paper`` has no pad force sensor: its noise reached nothing. The same value is taken where
    the reading exists (``extended``, and ``mixed``, which draws either set)."""
    value = _changed(path)
    with pytest.raises(FieldError) as refused:
        RunSpec(scenario="condition-2", sensor_set=sensor_set, overrides={path: value})
    _refused(refused, "RunSpec.overrides", path, value, f"sensor_set {sensor_set!r} has no")
    params = with_overrides(RigParams(), {path: value})
    with pytest.raises(FieldError) as refused:
        gym.make("MicroGravityLanding-v1", sensor_set=sensor_set, params=params)
    _refused(refused, "params", path, value, f"sensor_set {sensor_set!r} has no")
    RunSpec(scenario="condition-2", overrides={path: value})
    TaskSettings(sensor_set="mixed", params=params)


def test_the_paper_sensor_set_takes_the_accelerometer_it_still_reads_into_the_metrics():
    """Its accelerometer is not observed, but its reading is the ``accelerometer_descent_accel_m_s2``
    metric: its noise and bias have an effect and are taken."""
    unread = {path for _, path in UNREAD}
    sensors = {path: _changed(path) for path in DEFAULTS if path.startswith("sensors.") and path not in unread}
    assert "sensors.accelerometer_bias_m_s2" in sensors
    RunSpec(scenario="condition-2", sensor_set="paper", overrides=sensors)


def test_a_campaign_sweeping_a_parameter_its_imperfection_off_leaves_unused_is_refused_at_load():
    """Loaded, it ran every point bit-identically and a sensitivity page ranked the parameter as
    having no influence; now the point is named."""
    data = {
        "name": "t",
        "base": {"scenario": "condition-2", "duration_s": 0.3, "imperfections": {"friction": False}},
        "sweep": {"qzs.guide_damping_n_s_per_m": [50.0, 20.0]},
    }
    with pytest.raises(ValueError, match=r"^at \{'qzs.guide_damping_n_s_per_m': 20.0\}: RunSpec.overrides ") as error:
        Campaign.from_dict(data)
    assert "imperfection 'friction' is off, which sets it to 0.0" in str(error.value)


def test_the_paper_rig_is_built_once_and_each_caller_gets_its_own_paths():
    """The spec expansion's shortcuts: one ``RigParams()``, no copy for no override, and a mutated
    path table that is the caller's alone (the cached one stays the paper's)."""
    from microg_env.params import paper_rig

    paths = parameter_paths()
    paths["pad.stiffness_n_per_m"] = -1.0
    assert parameter_paths()["pad.stiffness_n_per_m"] == RigParams().pad.stiffness_n_per_m
    assert paper_rig() is paper_rig()
    assert paper_rig() == RigParams()
    rig = with_overrides(RigParams(), {"pad.damping_n_s_per_m": 150.0})
    assert with_overrides(rig, {}) is rig
    mine = parameter_paths(rig)
    mine["pad.damping_n_s_per_m"] = -1.0
    assert parameter_paths(rig)["pad.damping_n_s_per_m"] == 150.0


def test_an_override_asked_again_is_the_rig_made_before_and_tells_like_values_apart(monkeypatch):
    """A campaign asks ``with_overrides`` for the same rig thousands of times: it is made once, in
    a store of bounded size. Values equal in Python but not as overrides (1.0 and 1 or True; 0.0
    and -0.0) are not confused, nor an equal base rig with the one asked before."""
    from microg_env import params as module

    monkeypatch.setattr(module, "_OVERRIDDEN", {})
    monkeypatch.setattr(module, "_MAX_KEPT", 3)
    base = RigParams()
    made = with_overrides(base, {"pad.damping_n_s_per_m": 150.0})
    assert with_overrides(base, {"pad.damping_n_s_per_m": 150.0}) is made
    assert with_overrides(base, {"pad.damping_n_s_per_m": 151.0}).pad.damping_n_s_per_m == 151.0
    assert repr(with_overrides(base, {"pad.damping_n_s_per_m": 150}).pad.damping_n_s_per_m) == "150"
    with_overrides(base, {"pad.damping_n_s_per_m": 1.0})
    with pytest.raises(ValueError, match="must be a number, got True"):  # 1.0 taken: True is still refused
        with_overrides(base, {"pad.damping_n_s_per_m": True})
    zero = with_overrides(base, {"sensors.ruler_zero_offset_m": 0.0}).sensors.ruler_zero_offset_m
    negative = with_overrides(base, {"sensors.ruler_zero_offset_m": -0.0}).sensors.ruler_zero_offset_m
    assert (math.copysign(1.0, zero), math.copysign(1.0, negative)) == (1.0, -1.0)
    equal = replace(base, sensors=replace(base.sensors, ruler_zero_offset_m=-0.0))  # == base, not base
    assert equal == base
    again = with_overrides(equal, {"pad.damping_n_s_per_m": 150.0})
    assert math.copysign(1.0, again.sensors.ruler_zero_offset_m) == -1.0  # made from its own base
    assert len(module._OVERRIDDEN) <= 3
