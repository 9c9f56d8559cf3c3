"""The landing task over N rigs as arrays: one code path for the single env (N = 1) and the vector env.

:class:`LandingCore` takes the task's settings (:class:`~microg_env.task.TaskSettings`,
checked there), builds the rig, draws each rig's episode
(schedule, domain randomisation, start height, balancer drift) from that rig's own generator, and
steps N rigs together: the episode's model field values (test weights placed, pad law, balancer
trim, randomised lander and friction) are written per rig (:meth:`Rig.episode_fields`), and the
command delay, the drive's interpolated reference, balancer drift, load placement, sensors,
reward and termination are array functions over the rigs being stepped. The physics is a
:class:`~microg_env.sim.physics.ModelPhysics` (one ``MjData``) or a
:class:`~microg_env.sim.physics.BatchPhysics` (``mujoco.batch``); everything else is the same.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from microg_env import scores, validate
from microg_env.compiled import mj_step
from microg_env.controllers.base import tell_plants
from microg_env.controllers.pid import PID
from microg_env.controllers.registry import make_controller
from microg_env.envs import period
from microg_env.imperfections import apply_imperfections
from microg_env.interface import (
    DESCENT_LIMIT_M_S,
    MAX_SPEED_M_S,
    MIXED_SENSORS,
    OBSERVATION_INDEX,
    SCALES,
    SENSOR_SETS,
    action_size,
    gain_scales,
    gated_actions,
    gated_setpoint,
    highpass_gain,
    speed_commands_m_s,
)
from microg_env.params import MAX_CONTROL_STEPS, RigParams
from microg_env.scenarios import SETTLE_S, LoadStep, Scenario, ideal_descent_m_s2
from microg_env.sim.limits import check_pad
from microg_env.sim.model import (
    SLEW_PARAMETER,
    Rig,
    build_rig,
    flexible_unit,
    validate_loads,
)
from microg_env.sim.physics import BatchPhysics, ModelPhysics
from microg_env.sim.sensors import NoiseDraws, SensorModel
from microg_env.task import TaskSettings
from microg_env.validate import FieldError

#: Margin before a stroke end (or the pad's full depth) at which the episode terminates, m.
STOP_MARGIN_M = 1e-4
#: Clearance the start height keeps above the pad and above every load's switch height, m.
START_CLEARANCE_M = 1e-3
#: A rig's descent state (period.score_descent: window start s, velocity there, ideal acceleration,
#: last velocity error, touched) before its first weight is placed: no window.
NO_DESCENT = (np.inf, np.nan, 0.0, 0.0, 0.0)
#: Why an episode terminated, by code (0: it did not).
TERMINATION_REASONS = (None, "guide_stroke_limit", "screw_stroke_limit", "pad_bottomed_out")
_REASONS = np.array(TERMINATION_REASONS, dtype=object)  # indexed by the codes: new object arrays
#: The true physical state (and reward) every step reports in ``info``, in this order.
STATE_KEYS = (
    "time_s",
    "x_m",
    "foot_height_m",
    "lander_velocity_m_s",
    "lander_accel_m_s2",
    "accelerometer_m_s2",
    "support_position_m",
    "support_velocity_m_s",
    "support_force_deviation_n",
    "pad_force_n",
    "placed_load_kg",
    "stage",
    "command_m_s",
    "setpoint_m",
    "servo_torque_n_m",
    "compensation_error",
    "reward_x",
    "descent_velocity_error_m_s",
)
#: What ``info`` holds: the state, why the episode terminated, and the episode's sensor set (the
#: drawn one with ``sensor_set="mixed"``).
INFO_KEYS = (*STATE_KEYS, "termination_reason", "sensor_set")
#: The ``info`` key of an episode's normalised score, at the step that ends it (:mod:`microg_env.scores`).
SCORE_KEY = "normalized_score"


@dataclass(frozen=True)
class Episode:
    """What a reset draws for one rig."""

    params: RigParams  # the rig (a draw of the domain randomisation, if any)
    scenario: Scenario  # the schedule (drawn, with the drawn test weights)
    height_m: float  # the foot's start height above the pad
    drift_rate_k_per_s: float  # the balancer gas's temperature rate
    sensor_set: str  # the rig's sensors (a key of SENSOR_SETS)


class LandingCore:
    """N rigs of ``MicroGravityLanding-v1`` with the task's ``settings`` (the environment's keywords;
    see its docstring).

    ``scenarios`` gives each rig its own schedule (N of them; instead of ``scenario``/``condition``).
    ``batched`` steps the rigs on ``mujoco.batch`` with ``nthread`` threads (0: one per usable core); else
    the one rig steps its own ``MjData``.
    """

    def __init__(
        self,
        num_rigs: int = 1,
        settings: TaskSettings | None = None,
        scenarios: Sequence[Scenario] | None = None,
        batched: bool = False,
        nthread: int = 0,
    ) -> None:
        if not batched and num_rigs != 1:
            raise ValueError(f"{num_rigs} rigs need batched=True (one MjData holds one rig)")
        settings = TaskSettings() if settings is None else validate.instance("settings", settings, TaskSettings)
        self.settings = settings
        self.num_rigs = num_rigs
        if scenarios is not None:
            if settings.scenario_sampler is not None:
                raise ValueError("give scenario (or scenarios) or scenario_sampler, not both")
            if settings.scenario is not None:
                raise ValueError("give scenario or scenarios (one per rig), not both")
            scenarios = tuple(scenarios)
            if len(scenarios) != num_rigs:
                raise ValueError(f"scenarios must give one Scenario per rig ({num_rigs}), got {len(scenarios)}")
            for i, each in enumerate(scenarios):
                validate.instance(f"scenarios[{i}]", each, Scenario)
        self.scenarios = scenarios if scenarios is not None else (settings.schedule,) * num_rigs
        self.scenario = self.scenarios[0]
        self.base_params = settings.params
        # the observation entries each sensor set lacks (True: they read 0), and each rig's episode's row
        self._missing_by_set = {
            name: np.isin(np.arange(len(SCALES)), [OBSERVATION_INDEX[entry] for entry in missing])
            for name, missing in SENSOR_SETS.items()
        }
        self._sensors_drawn = self.settings.sensor_set == MIXED_SENSORS
        fixed = "extended" if self._sensors_drawn else self.settings.sensor_set
        self._missing_by_rig = np.tile(self._missing_by_set[fixed], (num_rigs, 1))
        self._sensor_set_by_rig = np.full(num_rigs, fixed, dtype=object)  # each episode's, for info
        # a fixed set's columns (also the compiled PID loop's, which a mixed set does not run)
        self._missing = np.flatnonzero(self._missing_by_set[fixed])
        self._hidden = np.array([OBSERVATION_INDEX[name] for name in self.settings.hidden_observations], dtype=np.int64)
        for each in set(self.scenarios):
            _check_reset_noise(self.settings.reset_noise_scale, each)

        schedules = tuple(dict.fromkeys(self.scenarios))
        nominal = [apply_imperfections(s.rig_params(self.base_params), self.settings.imperfections) for s in schedules]
        if self.settings.scenario_sampler is not None:
            schedules = self.settings.scenario_sampler.extremes(nominal[0].lander.mass_kg, nominal[0].gravity_m_s2)
            nominal = nominal[:1] * len(schedules)
        for each, schedule in zip(nominal, schedules, strict=True):
            self._check_scenario_fits(each, schedule)
        most_loads = max(schedules, key=lambda s: len(s.loads))
        self.rig: Rig = build_rig(
            nominal[0],
            most_loads.loads_kg,
            xml_file=self.settings.xml_file,
            physics_step_s=self.settings.physics_step_s,
            ideal_drive=not self.settings.imperfections.servo_lag,
            drive_scheme=self.settings.drive_scheme,
        )
        for each in nominal[1:]:
            self.rig.check_episode_params(each)  # one compiled model for every rig's schedule
        self.nominal_params = nominal[0]
        self.physics = BatchPhysics(self.rig.model, num_rigs, nthread) if batched else ModelPhysics(self.rig.model)
        self.sensors = SensorModel(
            self.nominal_params, self.settings.control_period_s, self.settings.imperfections.sensor_noise
        )
        self._noise = NoiseDraws(num_rigs)
        params = self.nominal_params
        self.x_limit_m = params.qzs.stroke_m / 2.0 - STOP_MARGIN_M
        low, high = params.screw.range_m
        self._screw_limits = (low + STOP_MARGIN_M, high - STOP_MARGIN_M)
        self._floor = -(params.pad.thickness_m - STOP_MARGIN_M)
        rig, model = self.rig, self.rig.model
        self._drift_dof = rig.screw_dof if params.balancer.placement == "frame_support" else rig.qzs_dof
        self._accel_adr = int(model.sensor_adr[model.sensor("lander_accel").id]) + 2
        self._force_adr = int(model.sensor_adr[model.sensor("pad_force").id])
        self.base = (
            make_controller(self.settings.base_controller, self.settings.control_period_s, self.base_params)
            if self.settings.action_mode != "speed"
            else None
        )

        n = num_rigs
        #: Each rig's episode (None before its first reset).
        self.episodes: list[Episode | None] = [None] * n
        self.observation = np.zeros((n, len(SCALES)), dtype=np.float32)
        self.steps = np.zeros(n, dtype=np.int64)
        self.max_steps = np.zeros(n, dtype=np.int64)
        self.scenario_periods = np.zeros(n, dtype=np.int64)  # the control periods of the rig's schedule
        self.episode_return = np.zeros(n)  # the sum of the rig's step rewards this episode
        #: The task's normalised score (None: a task made otherwise than a scored id registers it).
        self.score = scores.REFERENCES.get(scores.scored_id(settings))
        #: Most control periods an episode runs whatever its schedule (a vector env's ``max_episode_steps``).
        self.period_limit = MAX_CONTROL_STEPS
        self.next_load = np.zeros(n, dtype=np.int64)
        self.placed = np.zeros((n, len(rig.load_bodies)), dtype=bool)
        self.placed_load_kg = np.zeros(n)
        self.loads_kg = np.zeros((n, len(rig.load_bodies)))
        self.switch_height_m = np.full((n, len(rig.load_bodies)), np.inf)  # inf: placed at t = 0
        self.load_count = np.zeros(n, dtype=np.int64)
        self.reference_weight_n = np.ones(n)
        self.previous_action = np.zeros(n)
        self.pending_command = np.zeros(n)  # m/s, reaching the drive at the next period (control delay)
        self.command = np.zeros(n)  # m/s, the command the drive last received
        self.base_command = np.zeros(n)  # m/s, the base controller's last command (residual mode)
        # The residual's high-pass (interface.residual_setpoint): its last input and output, and
        # its first stage's last output if it has two.
        self._residual_gain = highpass_gain(
            self.settings.residual_highpass_hz, self.settings.decision_period * self.settings.control_period_s
        )
        self.residual_action = np.zeros(n)
        self.residual_setpoint_m = np.zeros(n)
        self.residual_stage_m = np.zeros(n) if self.settings.residual_highpass_order == 2 else None
        self.position_ref = np.zeros(n)  # the drive's interpolated position reference, motor rad
        self.motor_speed = np.full(n, np.nan)  # rad/s at the last physics step (midpoint drive); NaN: none yet
        self.drift_n_per_s = np.zeros(n)
        self.x_stiffness = np.zeros(n)
        self.trim_height_m = np.zeros(n)
        self.gravity = np.full(n, params.gravity_m_s2)
        self.last_readings = np.zeros((2, n))  # ruler and encoder at the previous period
        self.accelerometer = np.zeros(n)  # the accelerometer's last reading, m/s^2
        self.fresh = np.ones(n, dtype=bool)  # no previous reading yet: rates are 0
        self.reward_x = np.zeros(n)  # the x term of the last control period's reward
        self.reward = np.zeros(n)  # the last control period's reward (period.observe)
        self.descent = np.tile(NO_DESCENT, (n, 1))  # each rig's descent window (period.score_descent)
        self._positions = np.arange(n)
        self._period_span_s = (
            self.settings.physics_step_s * self.settings.frame_skip
        )  # the drive's reference ramps this long
        self._no_field = np.zeros((0, 0, 0))  # the ideal drive has no slew limiter to set
        self._no_setpoint = np.zeros(0)  # no base controller: the state's setpoint is 0
        self._no_commands = np.zeros(0)  # no base controller: the drive takes the actions
        # scratch arrays of a control period, read before the next
        self._height, self._codes, self._going = np.empty(n), np.empty(n, dtype=np.int64), np.empty(n, dtype=bool)

    # -- episodes ------------------------------------------------------------------------------

    def _check_scenario_fits(self, params: RigParams, scenario: Scenario) -> None:
        """Reject, before any episode, a schedule the rig cannot run (named in the error)."""
        top = params.screw.range_m[1] - STOP_MARGIN_M - 0.01
        if scenario.descent_height_m + self.settings.reset_noise_scale > top:
            noise = (
                f" plus reset_noise_scale {self.settings.reset_noise_scale!r} m"
                if self.settings.reset_noise_scale
                else ""
            )
            raise FieldError(
                f"Scenario.descent_height_m {scenario.descent_height_m!r} m{noise} is above the screw's reach "
                f"({top:.3f} m)",
                "Scenario.descent_height_m",
            )
        steps = round(scenario.duration_s / self.settings.control_period_s)
        if steps < 1:
            raise FieldError(
                f"Scenario.duration_s {scenario.duration_s:g} s is shorter than one control period "
                f"({self.settings.control_period_s:g} s)",
                "Scenario.duration_s",
            )
        if steps > MAX_CONTROL_STEPS:
            raise FieldError(
                f"Scenario.duration_s {scenario.duration_s:g} s at control_period_s "
                f"{self.settings.control_period_s:g} s "
                f"is {steps} control steps, more than the {MAX_CONTROL_STEPS} one run may take",
                "Scenario.duration_s",
                "control_period_s",
            )
        g, mass, load = params.gravity_m_s2, params.lander.mass_kg, sum(scenario.loads_kg)
        validate_loads(scenario.loads_kg, mass)
        highest = replace(scenario, descent_height_m=scenario.descent_height_m + self.settings.reset_noise_scale)
        speed = highest.impact_speed_m_s(mass, g)
        check_pad(params, mass + load, speed, load * g, self.settings.physics_step_s, scenario.name)
        if self.settings.domain_randomization is not None:
            self.settings.domain_randomization.check(params, highest, self.settings.physics_step_s)

    def draw_episode(self, rig: int, rng: np.random.Generator) -> Episode:
        """Rig ``rig``'s next episode: its rig, schedule, start height and balancer drift, drawn from ``rng``."""
        scenario = self.scenarios[rig]
        params = apply_imperfections(scenario.rig_params(self.base_params), self.settings.imperfections)
        if self.settings.scenario_sampler is not None:
            scenario = self.settings.scenario_sampler.sample(
                rng, self.base_params.lander.mass_kg, self.base_params.gravity_m_s2
            )
        if self.settings.domain_randomization is not None:
            drawn, loads = self.settings.domain_randomization.sample(
                self.scenarios[rig].rig_params(self.base_params), scenario.loads_kg, rng
            )
            params = apply_imperfections(drawn, self.settings.imperfections)
            steps = tuple(LoadStep(mass, step.height_m) for mass, step in zip(loads, scenario.loads, strict=True))
            scenario = replace(scenario, loads=steps)
        height = scenario.descent_height_m
        if self.settings.reset_noise_scale > 0:
            height += rng.uniform(-self.settings.reset_noise_scale, self.settings.reset_noise_scale)
        drift = params.drift
        rate = (
            rng.uniform(-1.0, 1.0) * drift.max_temperature_rate_k_per_s
            if self.settings.imperfections.balancer_drift
            else 0.0
        )
        sensors = self.settings.sensor_set
        if self._sensors_drawn:  # from a child of ``rng``: what ``rng`` draws stays the fixed sets'
            sensors = tuple(SENSOR_SETS)[rng.spawn(1)[0].integers(len(SENSOR_SETS))]
        return Episode(params, scenario, height, rate, sensors)

    def reset(self, ids: np.ndarray, rngs: Sequence[np.random.Generator]) -> None:
        """Start a new episode on rigs ``ids``, each drawn from its generator ``rngs[rig]``.

        Every draw and check comes before anything is written, so a reset that raises changes no rig.
        """
        ids = np.asarray(ids, dtype=np.int64)
        episodes = [self.draw_episode(int(i), rngs[i]) for i in ids]
        nobody = np.zeros(len(self.rig.load_bodies), dtype=bool)
        writes = [self.rig.episode_fields(e.params, e.scenario.loads_kg, nobody, e.height_m) for e in episodes]
        physics, rig = self.physics, self.rig
        for i, episode, fields in zip(ids, episodes, writes, strict=True):
            self.episodes[i] = episode
            physics.write(int(i), fields)
            loads = np.zeros(len(rig.load_bodies))
            switch = np.full(len(rig.load_bodies), np.inf)
            for k, load in enumerate(episode.scenario.loads):
                loads[k] = load.mass_kg
                switch[k] = np.inf if load.height_m is None else load.height_m
            self.loads_kg[i], self.switch_height_m[i] = loads, switch
            self.load_count[i] = len(episode.scenario.loads)
            unit = flexible_unit(episode.params)
            self.drift_n_per_s[i] = (
                unit.balancer_force_n * episode.drift_rate_k_per_s / episode.params.drift.gas_temperature_k
            )
            self.x_stiffness[i] = unit.x_stiffness_n_per_m
            periods = round(episode.scenario.duration_s / self.settings.control_period_s)
            self.scenario_periods[i] = periods
            self.max_steps[i] = min(periods, self.period_limit)
            self.reference_weight_n[i] = episode.scenario.loads[0].mass_kg * episode.params.gravity_m_s2
            self.gravity[i] = episode.params.gravity_m_s2
            self.trim_height_m[i] = episode.height_m
            self._missing_by_rig[i] = self._missing_by_set[episode.sensor_set]
            self._sensor_set_by_rig[i] = episode.sensor_set
        physics.reset(ids)
        for i, episode in zip(ids, episodes, strict=True):
            for name, index, value in rig.start_state(episode.params, episode.height_m):
                getattr(physics, name)[i, index] = value
        self.position_ref[ids] = 0.0 if rig.ideal_drive else physics.ctrl[ids, 0]
        self.motor_speed[ids] = np.nan
        self.steps[ids] = 0
        self.episode_return[ids] = 0.0
        self.next_load[ids] = 0
        self.placed[ids] = False
        self.placed_load_kg[ids] = 0.0
        self.previous_action[ids] = 0.0
        self.pending_command[ids] = 0.0
        self.command[ids] = 0.0
        self.base_command[ids] = 0.0
        self.residual_action[ids] = 0.0
        self.residual_setpoint_m[ids] = 0.0
        if self.residual_stage_m is not None:
            self.residual_stage_m[ids] = 0.0
        self.fresh[ids] = True
        self.descent[ids] = NO_DESCENT
        self._noise.restart(ids)
        if self.base is not None:
            self.base.reset(ids)
            # an oracle base knows them
            tell_plants(self.base, ids, [self.episodes[i].params for i in ids], ideal_drive=self.rig.ideal_drive)
        self._place_due_loads(ids, self.trim_height_m[ids])
        physics.forward(ids)
        self._observe(ids, rngs)

    def _place_due_loads(self, ids: np.ndarray, height_m: np.ndarray) -> None:
        """Place the test weights whose switch height the foot has come down to (Scenario.loads_due)."""
        placed = self.placed[ids] | (height_m[:, None] <= self.switch_height_m[ids])
        placed &= np.arange(placed.shape[1]) < self.load_count[ids, None]
        placed = np.cumsum(~placed, axis=1) == 0  # in order: a weight waits for the one before it
        changed = np.flatnonzero((placed != self.placed[ids]).any(axis=1))
        for j in changed:
            i = int(ids[j])
            episode = self.episodes[i]
            self.physics.write(
                i, self.rig.episode_fields(episode.params, episode.scenario.loads_kg, placed[j], self.trim_height_m[i])
            )
            self.placed[i] = placed[j]
            self.next_load[i] = int(placed[j].sum())
            self.placed_load_kg[i] = float(np.dot(self.loads_kg[i], placed[j]))
            # The compensation error is measured against the weight placed (the first before any is).
            reference = max(self.placed_load_kg[i], self.loads_kg[i, 0])
            g = episode.params.gravity_m_s2
            self.reference_weight_n[i] = reference * g
            if not self.descent[i, 4]:  # the stage's descent window: SETTLE_S on, until the pad is touched
                ideal = ideal_descent_m_s2(reference, episode.params.lander.mass_kg, g)
                self.descent[i, :3] = (self.steps[i] * self.settings.control_period_s + SETTLE_S, np.nan, ideal)

    # -- stepping ------------------------------------------------------------------------------

    def step(
        self, ids: np.ndarray, actions: np.ndarray, rngs: Sequence[np.random.Generator]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One environment step of rigs ``ids`` (sorted, unique) with ``actions`` (clipped, flat:
        :func:`~microg_env.interface.action_size` numbers per rig): the action held for
        ``decision_period`` control periods or until the rig's episode ends. A ``gains`` action
        sets the base PID's gain multipliers (:func:`~microg_env.interface.gain_scales`; 1 while a
        ``residual_gate_m`` reads the foot above it); the mean of its components is the rig's
        previous action (the observation's entry 8).

        Returns the mean reward over the periods run, the termination codes
        (:data:`TERMINATION_REASONS`), whether each was truncated, and the periods run.
        """
        if self.settings.action_mode == "gains":
            actions = actions.reshape(ids.size, action_size("gains"))
            gated = gated_actions(actions, self.observation[ids], self.settings.residual_gate_m)
            self.base.schedule(ids, gain_scales(gated, self.settings.gain_limit))
            actions = actions.mean(axis=1)
        elif self.base is not None:
            self.base.setpoint_m[ids] = gated_setpoint(
                actions,
                self.observation[ids],
                ids,
                self.settings.residual_gate_m,
                self.settings.residual_gate_on,
                self.settings.residual_limit_m,
                self._residual_gain,
                (self.residual_action, self.residual_setpoint_m, self.residual_stage_m),
            )
        # a speed action below the default limit: sent as the command its drive action (over MAX_SPEED_M_S,
        # float32) gives, so that a policy's controller, which returns that action, commands the same speed
        speeds_m_s = None
        if self.settings.action_mode == "speed" and self.settings.speed_limit_m_s != MAX_SPEED_M_S:
            speeds_m_s = speed_commands_m_s(actions, self.settings.speed_limit_m_s)
        n = ids.size
        total, periods = np.zeros(n), np.zeros(n, dtype=np.int64)
        codes, truncated = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool)
        positions, rigs = self._positions[:n], ids  # the rigs still running and their places in ids
        for _ in range(self.settings.decision_period):
            command = self._no_commands  # the drive takes the actions themselves
            if speeds_m_s is not None:
                command = speeds_m_s[positions]
            if self.base is not None:
                command = self.base(self.observation[rigs], ids=rigs)[:, 0].astype(np.float64) * MAX_SPEED_M_S
                self.base_command[rigs] = command
            code = self._control_period(rigs, positions, actions, command, rngs)
            going = self._going[: rigs.size]
            left = period.tally(
                rigs, positions, code, self.steps, self.max_steps, self.reward, total, periods, codes, truncated,
                going,
            )  # fmt: skip
            if left == 0:
                break
            if left < rigs.size:
                positions, rigs = positions[going], rigs[going]
        reward = total / periods
        self.episode_return[ids] += reward
        return reward, codes, truncated, periods

    def shortfall(self, ids: np.ndarray) -> np.ndarray:
        """How far rigs ``ids``' returns so far fall short of a whole episode's most (a step pays at
        most 1): its steps, the schedule's control periods over the decision period rounded up,
        minus the return (:mod:`microg_env.scores`)."""
        whole = -(-self.scenario_periods[ids] // self.settings.decision_period)
        return whole - self.episode_return[ids]

    def scores(self, ids: np.ndarray, codes: np.ndarray, truncated: np.ndarray) -> np.ndarray:
        """The normalised scores of rigs ``ids`` whose episodes just ended by themselves (``codes``
        not 0: terminated; ``truncated`` at the schedule's end), NaN for the others, which a step
        limit cut short or which go on. Only on a task with a score (:attr:`score`)."""
        own_end = (codes != 0) | (truncated & (self.steps[ids] >= self.scenario_periods[ids]))
        return np.where(own_end, self.score.score(self.shortfall(ids)), np.nan)

    def can_run_pid(self, controller: Any) -> bool:
        """Whether :meth:`run_pid` can drive this core's rig with ``controller``: a :class:`PID`
        itself (not a subclass, which may act otherwise), on one rig stepping its own ``MjData``,
        its actions the drive's speeds at the default limit, one period per step, every observation entry shown, the
        rig's sensor set fixed."""
        return (
            type(controller) is PID
            and isinstance(self.physics, ModelPhysics)
            and self.base is None
            and self.settings.speed_limit_m_s == MAX_SPEED_M_S
            and self.settings.decision_period == 1
            and not self._hidden.size
            and not self._sensors_drawn
            and mj_step is not None
        )

    def run_pid(
        self,
        pid: PID,
        count: int,
        rngs: Sequence[np.random.Generator],
        states: np.ndarray,
        rewards: np.ndarray,
        row: int,
    ) -> tuple[int, int | None]:
        """Up to ``count`` steps of the one rig (:meth:`can_run_pid`) with ``pid`` choosing each
        action from the observation, as ``step(ids, pid(observation))`` would take them, bit for
        bit, in one compiled loop (:func:`~microg_env.envs.period.pid_periods`): each step's reward
        into ``rewards`` and :meth:`state` into ``states``, from row ``row`` on. Returns the steps
        taken and, if the episode ended, its termination code (a truncation's is 0)."""
        ids = self._positions[:1]
        actions, codes = np.zeros(1), self._codes[:1]
        sums = (np.zeros(1), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=bool))
        sums = (*sums, self._going[:1])  # the step's total, periods, codes, truncated, going
        tally_args, state_args = (ids, ids, codes, self.steps, self.max_steps, self.reward), self._state_args(ids)
        args = (
            ids, actions, self.observation, pid.kernel_args(), self._drive_args(ids, ids, actions, self._no_commands),
            self._observe_args(ids, codes, self._height[:1]), tally_args, sums, state_args, self._missing, states,
            rewards,
        )  # fmt: skip
        speed = (self.rig.midpoint_drive, self._speed_args(ids))
        model, data = self.physics.model._address, self.physics.data._address
        done = 0
        while done < count:
            ran, why = period.pid_periods(
                count - done, model, data, self.settings.frame_skip, *args, row + done, *speed
            )
            done += ran
            if why == period.NON_FINITE:
                raise ValueError(f"action must be finite, got {float(actions[0])!r}")
            if why == period.OBSERVE_HERE:  # the period's physics ran: read (draws, weights) and finish it
                self._observe(ids, rngs)
                period.finish_period(tally_args, sums, state_args, states, rewards, row + done)
                done += 1
            self._noise.exhausted |= why == period.NOISE_USED
            if sums[2][0] != 0 or sums[3][0]:
                self._add_returns(rewards[row : row + done])
                return done, int(sums[2][0])
        self._add_returns(rewards[row : row + done])
        return done, None

    def _add_returns(self, rewards: np.ndarray) -> None:
        """The one rig's step ``rewards`` added to its return one by one, as :meth:`step` adds them."""
        for reward in rewards.tolist():
            self.episode_return[0] += reward

    def _control_period(
        self,
        ids: np.ndarray,
        positions: np.ndarray,
        actions: np.ndarray,
        command_m_s: np.ndarray,
        rngs: Sequence[np.random.Generator],
    ) -> np.ndarray:
        """Advance rigs ``ids`` (at ``positions`` of ``actions``) one control period with the drive
        taking ``command_m_s`` (empty: the actions, as speeds) after the delay, if on; place the test
        weights that came due, and read the sensors; returns the rigs' termination codes."""
        period.drive(*self._drive_args(ids, positions, actions, command_m_s))
        self._step_physics(ids)
        return self._observe(ids, rngs)

    def _step_physics(self, ids: np.ndarray) -> None:
        """The control period's physics steps of rigs ``ids``; with the midpoint drive, the drive's
        speed input set before each (:func:`~microg_env.envs.period.speed_inputs`)."""
        physics, count = self.physics, self.settings.frame_skip
        if not self.rig.midpoint_drive:
            physics.step(ids, count)
        elif isinstance(physics, ModelPhysics) and mj_step is not None:
            period.midpoint_steps(physics.model._address, physics.data._address, count, self._speed_args(ids))
        else:
            args = self._speed_args(ids)
            for _ in range(count):
                period.speed_inputs(*args)
                physics.step(ids, 1)

    def _speed_args(self, ids: np.ndarray) -> tuple:
        """:func:`~microg_env.envs.period.speed_inputs`' arguments for rigs ``ids``."""
        physics, rig = self.physics, self.rig
        return (
            ids, physics.ctrl, physics.qvel, rig.motor_dof, rig.gear, self.command, self.motor_speed,
            physics.field("actuator_gainprm"), rig.servo, self.settings.physics_step_s,
        )  # fmt: skip

    def _drive_args(
        self, ids: np.ndarray, positions: np.ndarray, actions: np.ndarray, command_m_s: np.ndarray
    ) -> tuple:
        """:func:`~microg_env.envs.period.drive`'s arguments for rigs ``ids``."""
        physics, rig = self.physics, self.rig
        ideal = rig.ideal_drive
        # the field looked up each time: a copy of the environment has its own model
        dynprm = self._no_field if ideal else physics.field("actuator_dynprm")
        return (
            ids, positions, actions, self.previous_action, command_m_s, self.settings.imperfections.control_delay,
            self.pending_command, self.command, self.steps, self.position_ref, self.drift_n_per_s, self._drift_dof,
            physics.qfrc_applied, physics.ctrl, dynprm, rig.servo, SLEW_PARAMETER, rig.gear, ideal, MAX_SPEED_M_S,
            self.settings.control_period_s, self._period_span_s,
        )  # fmt: skip

    def _observe(self, ids: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        """Place the test weights of rigs ``ids`` that came due, read their sensors into their
        observation rows (noise from each rig's generator) and score the period into ``reward``
        (x into ``reward_x``, the descent into ``descent``); returns their termination codes."""
        codes, height = self._codes[: ids.size], self._height[: ids.size]
        while True:
            if self.sensors.noisy and self._noise.exhausted:
                self._noise.refill(ids, rngs)
            result = period.observe(*self._observe_args(ids, codes, height))
            if result >= 0:
                self._noise.exhausted |= result == 1
                if self._missing.size:  # sensors the rig's set lacks read 0
                    self.observation[np.ix_(ids, self._missing)] = 0.0
                elif self._sensors_drawn:  # each rig's drawn set's
                    rows = self.observation[ids]
                    rows[self._missing_by_rig[ids]] = 0.0
                    self.observation[ids] = rows
                return codes
            if result == -1:
                due = ~np.isnan(height)
                self._place_due_loads(ids[due], height[due])
            else:  # -2: a rig's noise draws ran out
                self._noise.exhausted = True

    def _observe_args(self, ids: np.ndarray, codes: np.ndarray, height: np.ndarray) -> tuple:
        """:func:`~microg_env.envs.period.observe`'s arguments for rigs ``ids`` (``codes`` and
        ``height``: its outputs)."""
        physics, rig, sensors, noise, task = self.physics, self.rig, self.sensors, self._noise, self.settings
        low, high = self._screw_limits
        return (
            ids, physics.qpos, physics.sensordata, rig.screw_qpos, rig.qzs_qpos, rig.motor_qpos, self._accel_adr,
            self._force_adr, self.gravity, sensors.noisy, sensors.noise, sensors.bias, sensors.steps, noise.block,
            noise.used, self.last_readings, self.fresh, self.accelerometer, self.placed_load_kg,
            self.previous_action, self.base_command, SCALES, task.control_period_s, self.observation,
            self.reward_x, task.reward_scale_m, self.x_limit_m, low, high, self._floor, codes, self.next_load,
            self.load_count, self.switch_height_m, height, physics.qvel, rig.screw_dof, rig.qzs_dof, self.steps,
            self.descent, task.reward_descent_weight, task.reward_descent_scale_m_s, DESCENT_LIMIT_M_S, self.reward,
        )  # fmt: skip

    # -- what the rigs show ----------------------------------------------------------------------

    def foot_height(self, ids: np.ndarray) -> np.ndarray:
        """Height of the foot's sole above the undeformed pad, m (negative: deforming the pad)."""
        qpos = self.physics.qpos
        return qpos[ids, self.rig.screw_qpos] + qpos[ids, self.rig.qzs_qpos]

    def state(self, ids: np.ndarray) -> np.ndarray:
        """The true physical state of rigs ``ids``, (n, 18): one row per rig, one column per
        :data:`STATE_KEYS` entry."""
        out = np.empty((ids.size, len(STATE_KEYS)))
        period.state(*self._state_args(ids), out)
        return out

    def _state_args(self, ids: np.ndarray) -> tuple:
        """:func:`~microg_env.envs.period.state`'s arguments for rigs ``ids`` but its output."""
        physics, rig = self.physics, self.rig
        setpoint = self.base.setpoint_m if self.base is not None else self._no_setpoint
        return (
            ids, physics.qpos, physics.qvel, physics.qacc, physics.sensordata, physics.actuator_force,
            physics.qfrc_applied, rig.screw_qpos, rig.qzs_qpos, rig.screw_dof, rig.qzs_dof, rig.servo,
            self._force_adr, self._drift_dof == rig.qzs_dof, self.x_stiffness, self.steps,
            self.settings.control_period_s,
            self.accelerometer, self.placed_load_kg, self.next_load, self.command, setpoint,
            self.reference_weight_n, self.reward_x, self.descent,
        )  # fmt: skip

    def shown(self, ids: np.ndarray | None = None) -> np.ndarray:
        """A copy of the observations of rigs ``ids`` (every rig by default) as the agent is shown
        them: its ``hidden_observations`` read 0 (the base controller of a residual reads
        :attr:`observation`, all of it)."""
        observations = self.observation.copy() if ids is None else self.observation[ids]
        if self._hidden.size:
            observations[:, self._hidden] = 0.0
        return observations

    def info(self, ids: np.ndarray, codes: np.ndarray) -> dict[str, np.ndarray]:
        """What ``info`` reports of rigs ``ids`` (:data:`INFO_KEYS`: the true physical state, the
        termination reason, the sensor set), one array entry per rig; new arrays, so they do not
        change as the rigs step."""
        columns = self.state(ids).T.copy()
        values = dict(zip(STATE_KEYS, columns, strict=True))
        values["stage"] = columns[STATE_KEYS.index("stage")].astype(np.int64)
        values["termination_reason"] = _REASONS[codes]
        values["sensor_set"] = self._sensor_set_by_rig[ids]
        return values


def check_actions(actions: Any, shape: tuple[int, ...]) -> np.ndarray:
    """The actions as floats clipped to [-1, 1], flat; NaN, infinite, non-numeric or wrongly shaped
    actions raise ValueError (``shape`` is (k,) for one rig, (N, k) for N: k numbers an action)."""
    if type(actions) is np.ndarray and actions.dtype.kind == "f" and actions.shape == shape == (1,):
        value = float(actions[0])  # one rig's action, as controllers and SB3 give it: the fast path
        if not math.isfinite(value):
            raise ValueError(f"action must be finite, got {value!r}")
        return np.array([min(max(value, -1.0), 1.0)])
    array = np.asarray(actions)
    if array.dtype.kind not in "fiu":  # not bool, complex, string or object
        raise ValueError(f"action must be a real-valued array of shape {shape}, got {actions!r}")
    if array.shape != shape:
        raise ValueError(f"action must have shape {shape}, got shape {array.shape}")
    values = array.reshape(-1).astype(np.float64)
    if not np.isfinite(values).all():
        raise ValueError(f"action must be finite, got {float(values[~np.isfinite(values)][0])!r}")
    return np.minimum(np.maximum(values, -1.0), 1.0)  # out-of-range actions are clipped to the drive's range


def _check_reset_noise(noise: float, scenario: Scenario) -> None:
    """The start-height perturbation (checked non-negative by TaskSettings) must keep the start clear
    of the pad and of every switch height of ``scenario``."""
    room = scenario.descent_height_m - max(scenario.lowest_switch_height_m, 0.0) - START_CLEARANCE_M
    if noise > 0 and noise > room:
        raise FieldError(
            f"reset_noise_scale {noise!r} m would start the foot below "
            f"{max(scenario.lowest_switch_height_m, 0.0) * 1e3:g} mm + 1 mm (the pad or a load's switch height); "
            f"at most {max(room, 0.0):.4g} m for {scenario.name}",
            "reset_noise_scale",
        )
