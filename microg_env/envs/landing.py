"""Gymnasium environment: drive the stroke amplifier so the rig simulates microgravity."""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from microg_env import scenarios, validate
from microg_env.controllers.base import MAX_SPEED_M_S, SetpointController
from microg_env.controllers.policy import RESIDUAL_LIMIT_M
from microg_env.controllers.registry import BASELINES, make_controller
from microg_env.envs.observation import OBSERVATION_INDEX, OBSERVATION_SCALES, SCALES
from microg_env.imperfections import DomainRandomization, Imperfections, apply_imperfections
from microg_env.params import CONTROL_PERIOD_RANGE_S, CONTROL_PERIOD_S, MAX_CONTROL_STEPS, PHYSICS_STEP_S, RigParams
from microg_env.scenarios import LoadStep, Scenario, ScenarioSampler
from microg_env.sim.limits import check_pad
from microg_env.sim.model import Rig, build_rig, check_physics_step, flexible_unit, validate_loads
from microg_env.sim.sensors import SensorModel, backward_difference

__all__ = ["OBSERVATION_INDEX", "OBSERVATION_SCALES", "MicroGravityLandingEnv"]

#: Margin before a stroke end (or the pad's full depth) at which the episode terminates, m.
STOP_MARGIN_M = 1e-4
#: Clearance the start height keeps above the pad and above every load's switch height, m.
START_CLEARANCE_M = 1e-3
#: Largest render size, pixels (MuJoCo's offscreen buffer is set by the model's offwidth/offheight).
MAX_RENDER_PIXELS = 8192
#: The actions the environment takes (``action_mode``).
ACTION_MODES = ("speed", "residual")


def x_reward(x_m: float, scale_m: float, limit_m: float) -> float:
    """The reward for holding x: 1 - log(1 + (x/scale)^2) / log(1 + (limit/scale)^2).

    In decades: it falls by the same amount for each decade that x grows, from ``scale`` (x's noise
    floor) to ``limit`` (the guide's half stroke), so it keeps a gradient from millimetres down to
    nanometres; it is 1 at x = 0 and 0 at the guide's end, never negative, so an episode that ends
    early only forgoes what it would have earned.
    """
    return 1.0 - math.log1p((x_m / scale_m) ** 2) / math.log1p((limit_m / scale_m) ** 2)


class MicroGravityLandingEnv(gym.Env):
    """
    ## Description
    The QZS microgravity simulation rig of Jia et al. (Actuators 2024, 13(9), 361), simulated in
    MuJoCo. A 620 kg lander hangs on a quasi-zero-stiffness (QZS) mechanism from a floating
    support, which a servo screw stage (the "stroke amplifier") moves; a nitrogen balancer carries
    the support's load. While the relative displacement x = z_lander - z_support stays at 0 the
    support force is constant and a small test weight m makes the lander fall at m g / (M + m),
    1e-3 to 1e-4 g, onto a soft rubber pad. The agent drives the stroke amplifier; every
    micrometre of x it lets through is a 36 mN force error (5.7e-6 g). Episodes follow the paper's
    test conditions (Table 2), a custom schedule, or schedules drawn for training.

    ## Action Space
    ``Box(-1, 1, (1,), float32)``, held for ``decision_period`` control periods:

    * ``action_mode="speed"`` (default): the servo drive's speed reference for the support, scaled
      to +-1250 mm/s (the mechanism's maximum, Section 4.1), up positive;
    * ``action_mode="residual"``: a setpoint for x, scaled to +-``residual_limit_m`` (1 um), on a
      base controller (``base_controller``: ``pid``, ``pid-dom`` or ``feedforward``) that commands the
      drive every control period from the latest observation. An action of 0 is the base controller.

    Out-of-range values are clipped to [-1, 1]; NaN, infinite, non-numeric or wrongly shaped
    actions raise ``ValueError``. The drive interpolates its position reference at the commanded
    speed through the control period and closes its own PI speed loop at every physics step.

    ## Observation Space
    ``Box(-inf, inf, (10,), float32)``, what the rig's sensors give, each divided by a scale
    (``OBSERVATION_SCALES``) to be of order one:

    | index | observation | sensor | scale |
    |---|---|---|---|
    | 0 | x | grating ruler (quantised, noisy) | 100 um |
    | 1 | rate of x | backward difference of the ruler | 1 mm/s |
    | 2 | support position above touchdown | servo encoder | 0.1 m |
    | 3 | support velocity | encoder backward difference | 0.1 m/s |
    | 4 | lander acceleration, up positive | accelerometer, g removed (noisy) | 0.1 m/s^2 |
    | 5 | pad contact force | pad force sensor (noisy) | 100 N |
    | 6 | foot height above the pad | encoder + ruler | 0.1 m |
    | 7 | test weights placed so far | load stage (known to the operator) | 1 kg |
    | 8 | the agent's previous action | - | 1 |
    | 9 | the base controller's speed command (residual mode; 0 otherwise) | - | 1.25 m/s |

    ## Rewards
    Per control period, ``x_reward(x) = 1 - log(1 + (x/x0)^2) / log(1 + (x_max/x0)^2)`` with x the
    true relative displacement, x0 = ``reward_scale_m`` (10 nm, twice the ruler's step) and x_max
    the guide's half stroke less the stop margin, 24.9 mm, where the episode ends: it falls by the
    same amount for every decade of x, from nanometres to millimetres, and lies in [0, 1]. A step's
    reward is its mean over the control periods it spans. Never negative, it never makes ending an
    episode pay. ``info["reward_x"]`` holds it.

    ## Starting State
    Balanced at rest with the foot at the scenario's descent height, plus a uniform perturbation
    of +-``reset_noise_scale`` m that must keep the start at least 1 mm above the pad and above
    every load's switch height (0 with a ``scenario_sampler``, which draws the height itself);
    x = 0, servo holding, the balancer trimmed at that height. The scenario's first test weight is
    placed at t = 0; later ones when the foot comes down to their height (condition 3: 1 kg more at
    25 mm).

    ## Episode End
    Terminated when x reaches the 50 mm guide stroke, the support the screw's 480 mm stroke, or
    the foot the pad's full depth (it bottoms out on the floor); ``info["termination_reason"]``
    names which. Truncated when the episode's scenario duration is reached (30 s for the paper's
    conditions), at any control period.

    ## Arguments
    ``gym.make("microg_env:MicroGravityLanding-v1", **kwargs)`` with

    | argument | default | meaning |
    |---|---|---|
    | ``condition`` | 1 | the paper's condition 1, 2 or 3 (unless ``scenario`` or ``scenario_sampler`` is given) |
    | ``scenario`` | None | a custom ``Scenario`` (load schedule, descent height, duration, overrides) |
    | ``scenario_sampler`` | None | a ``ScenarioSampler`` ("training", or its fields as a dict): a schedule per reset |
    | ``control_period_s`` | 1e-3 | control period: the paper's 1000, 500, 200 or 100 us, up to 10 ms |
    | ``physics_step_s`` | 1e-4 | physics step; it must divide the control period |
    | ``decision_period`` | 1 | control periods an action is held (the base controller still runs every one) |
    | ``action_mode`` | ``"speed"`` | ``"speed"`` or ``"residual"`` (see Action Space) |
    | ``base_controller`` | ``"pid"`` | the controller a residual action moves the setpoint of |
    | ``residual_limit_m`` | 1e-6 | the setpoint an action of +-1 stands for, m |
    | ``imperfections`` | ``Imperfections()`` | which non-ideal effects are on (or their flags as a dict) |
    | ``domain_randomization`` | None | a ``DomainRandomization`` (``True``: its defaults; or its fields as a dict) |
    | ``params`` | ``RigParams()`` | the rig (the scenario's explicit overrides are applied on top) |
    | ``xml_file`` | None | an MJCF template other than the packaged ``scene.xml`` |
    | ``reward_scale_m`` | 1e-8 | x0 of the reward, m |
    | ``reset_noise_scale`` | 0.0 | half-width of the start-height perturbation, m |
    | ``render_mode``, ``width``, ``height``, ``camera_name`` | None, 640, 480, "side" | rendering |

    ``info`` carries the reward and the true physical state: ``time_s``, ``x_m``,
    ``foot_height_m``, ``lander_velocity_m_s``, ``lander_accel_m_s2``, ``support_position_m``,
    ``support_velocity_m_s``, ``support_force_deviation_n``, ``pad_force_n``, ``placed_load_kg``,
    ``stage``, ``command_m_s`` (the speed command the drive received), ``setpoint_m``,
    ``servo_torque_n_m``, ``compensation_error``, ``reward_x`` and ``termination_reason``.

    Copies (``pickle``, ``cloudpickle``, ``copy.deepcopy``) carry the episode: a copy made mid-episode
    continues exactly as the original would.

    ## Version History
    * v1: the reward in decades of x (never negative; v0's exp(-(e/0.05)^2) was flat beyond a few
      micrometres and its action-rate penalty made ending pay); the residual action mode on a named
      base controller and the decision period; training schedules drawn at reset; an observation
      entry for the base command; the corrected rig of microg 0.2 (interpolated drive reference,
      converged physics step, LuGre guide friction, Eq. 17 read literally, balancer on the support).
    * v0: microg 0.1, a speed action, a compensation-error reward with an action-rate penalty.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 1000}

    def __init__(
        self,
        condition: int = 1,
        scenario: Scenario | None = None,
        scenario_sampler: ScenarioSampler | str | Mapping | None = None,
        control_period_s: float = CONTROL_PERIOD_S,
        physics_step_s: float = PHYSICS_STEP_S,
        decision_period: int = 1,
        action_mode: str = "speed",
        base_controller: str = "pid",
        residual_limit_m: float = RESIDUAL_LIMIT_M,
        imperfections: Imperfections | Mapping | None = None,
        domain_randomization: DomainRandomization | Mapping | bool | None = None,
        params: RigParams | None = None,
        xml_file: str | None = None,
        reward_scale_m: float = 1e-8,
        reset_noise_scale: float = 0.0,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera_name: str = "side",
    ) -> None:
        self.scenario_sampler = _sampler(scenario_sampler)
        if self.scenario_sampler is not None and scenario is not None:
            raise ValueError("give scenario or scenario_sampler, not both")
        self.scenario = scenarios.condition(condition) if scenario is None else scenario
        validate.instance("scenario", self.scenario, Scenario)
        self.imperfections = _imperfections(imperfections)
        self.domain_randomization = _randomization(domain_randomization)
        self.base_params = RigParams() if params is None else params
        validate.instance("params", self.base_params, RigParams)
        self.physics_step_s = check_physics_step(physics_step_s)
        self.control_period_s = _check_control_period(control_period_s, self.physics_step_s)
        self.frame_skip = round(self.control_period_s / self.physics_step_s)
        self.decision_period = validate.integer("decision_period", decision_period, 1, 1000)
        self.action_mode = validate.choice("action_mode", action_mode, ACTION_MODES)
        self.base_controller = validate.choice("base_controller", base_controller, BASELINES)
        self.residual_limit_m = validate.positive("residual_limit_m", residual_limit_m, "m", 1e-3)
        self.reward_scale_m = validate.between("reward_scale_m", reward_scale_m, 1e-12, 1e-3, "m")
        self.reset_noise_scale = _check_reset_noise(reset_noise_scale, self.scenario)
        if self.scenario_sampler is not None and self.reset_noise_scale > 0:
            raise ValueError(
                f"reset_noise_scale {reset_noise_scale!r} m: a scenario_sampler draws the start height itself "
                "(its descent_height_m range); give one or the other"
            )
        if render_mode is not None:
            validate.choice("render_mode", render_mode, tuple(self.metadata["render_modes"]))
        if render_mode == "human":
            _check_display()
        self.render_mode = render_mode
        self.xml_file = None if xml_file is None else str(xml_file)
        if self.xml_file is not None and (
            Path(self.xml_file).suffix.lower() != ".xml" or not Path(self.xml_file).is_file()
        ):
            raise ValueError(f"xml_file {self.xml_file!r} is not an .xml file")
        self._render_size = (
            validate.integer("width", width, 1, MAX_RENDER_PIXELS),
            validate.integer("height", height, 1, MAX_RENDER_PIXELS),
        )
        self._camera_name = validate.instance("camera_name", camera_name, str)
        self._renderer = None
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.control_period_s)}
        self._human_every = max(1, round(1.0 / (60.0 * self.control_period_s)))

        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(len(SCALES),), dtype=np.float32)

        params = apply_imperfections(self.scenario.rig_params(self.base_params), self.imperfections)
        schedules = (self.scenario,)
        if self.scenario_sampler is not None:
            schedules = self.scenario_sampler.extremes(params.lander.mass_kg, params.gravity_m_s2)
        for schedule in schedules:
            self._check_scenario_fits(params, schedule)
        self.rig: Rig = build_rig(
            params,
            schedules[0].loads_kg,
            xml_file=self.xml_file,
            physics_step_s=self.physics_step_s,
            ideal_drive=not self.imperfections.servo_lag,
        )
        self.model = self.rig.model
        self.data = mujoco.MjData(self.model)
        if camera_name not in {self.model.camera(i).name for i in range(self.model.ncam)}:
            cameras = ", ".join(self.model.camera(i).name for i in range(self.model.ncam))
            raise ValueError(f"camera_name must be one of the model's cameras ({cameras}), got {camera_name!r}")
        if render_mode == "rgb_array":
            offscreen = (self.model.vis.global_.offwidth, self.model.vis.global_.offheight)
            for name, size, most in zip(("width", "height"), self._render_size, offscreen, strict=True):
                validate.integer(name, size, 1, most)
        model = self.model
        self._accel_adr = int(model.sensor_adr[model.sensor("lander_accel").id]) + 2
        self._force_adr = int(model.sensor_adr[model.sensor("pad_force").id])
        self._x_limit = params.qzs.stroke_m / 2.0 - STOP_MARGIN_M
        low, high = params.screw.range_m
        self._screw_limits = (low + STOP_MARGIN_M, high - STOP_MARGIN_M)
        self._floor = -(params.pad.thickness_m - STOP_MARGIN_M)
        self._drift_dof = self.rig.screw_dof if params.balancer.placement == "frame_support" else self.rig.qzs_dof
        self._sensors = SensorModel(params, self.control_period_s, self.imperfections.sensor_noise)
        self._truth = np.zeros((4, 1))  # true sensor values, one rig (sim.sensors.SENSORS)
        self._raw_observation = np.zeros(len(SCALES))
        self._base: SetpointController | None = None
        if self.action_mode == "residual":
            self._base = make_controller(self.base_controller, self.control_period_s)
        self.params = params  # the episode's rig (a draw of the domain randomisation, if any)
        self.active_scenario = schedules[0]  # the episode's schedule (drawn, with the drawn test weights)
        self._episode: dict[str, Any] | None = None  # None until the first reset

    def _check_scenario_fits(self, params: RigParams, scenario: Scenario) -> None:
        """Reject, before any episode, a schedule the rig cannot run (named in the error)."""
        top = params.screw.range_m[1] - STOP_MARGIN_M - 0.01
        if scenario.descent_height_m + self.reset_noise_scale > top:
            noise = f" plus reset_noise_scale {self.reset_noise_scale!r} m" if self.reset_noise_scale else ""
            raise ValueError(
                f"Scenario.descent_height_m {scenario.descent_height_m!r} m{noise} is above the screw's reach "
                f"({top:.3f} m)"
            )
        steps = round(scenario.duration_s / self.control_period_s)
        if steps < 1:
            raise ValueError(
                f"Scenario.duration_s {scenario.duration_s:g} s is shorter than one control period "
                f"({self.control_period_s:g} s)"
            )
        if steps > MAX_CONTROL_STEPS:
            raise ValueError(
                f"Scenario.duration_s {scenario.duration_s:g} s at control_period_s {self.control_period_s:g} s "
                f"is {steps} control steps, more than the {MAX_CONTROL_STEPS} one run may take"
            )
        g, mass, load = params.gravity_m_s2, params.lander.mass_kg, sum(scenario.loads_kg)
        validate_loads(scenario.loads_kg, mass)
        highest = replace(scenario, descent_height_m=scenario.descent_height_m + self.reset_noise_scale)
        speed = highest.impact_speed_m_s(mass, g)
        check_pad(params, mass + load, speed, load * g, self.physics_step_s, scenario.name)
        if self.domain_randomization is not None:
            self.domain_randomization.check(params, highest, self.physics_step_s)

    # -- gymnasium API -------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            seed = validate.integer("seed", seed, 0)  # a plain int (Gymnasium refuses NumPy integers)
        generator = (self._np_random, self._np_random_seed)
        try:
            super().reset(seed=seed)
            params, scenario, height, rate = self._draw_episode(self.np_random)
            self.rig.configure(params, scenario.loads_kg)  # checks before it writes
        except BaseException:  # a failed reset leaves the environment exactly as it was
            self._np_random, self._np_random_seed = generator
            raise
        self.params, self.active_scenario = params, scenario
        self.rig.reset(self.data, height)
        unit = flexible_unit(params)
        self._episode = {
            "next_load": 0,
            "previous_action": 0.0,
            "pending_command": 0.0,  # m/s, reaching the drive at the next period (control delay)
            "command": 0.0,  # m/s, the command the drive last received
            "base_command": 0.0,  # m/s, the base controller's last command (residual mode)
            "position_ref": float(self.data.ctrl[0]) if not self.rig.ideal_drive else 0.0,
            "steps": 0,
            "max_steps": round(scenario.duration_s / self.control_period_s),
            "last_readings": None,
            "drift_n_per_s": unit.balancer_force_n * rate / params.drift.gas_temperature_k,
            "x_stiffness": unit.x_stiffness_n_per_m,
            "reference_weight_n": scenario.loads[0].mass_kg * params.gravity_m_s2,
        }
        if self._base is not None:
            self._base.reset()
        self._place_due_loads(height)
        mujoco.mj_forward(self.model, self.data)
        self._observation = self._sense()
        self._info_now = self._info(None)
        if self.render_mode == "human":
            self.render()
        return self._observation, self._info_now

    def _draw_episode(self, rng: np.random.Generator) -> tuple[RigParams, Scenario, float, float]:
        """The episode's rig, schedule, start height and balancer drift rate (K/s), drawn and checked."""
        params, scenario = self.rig.params, self.scenario
        if self.scenario_sampler is not None:
            scenario = self.scenario_sampler.sample(rng, self.base_params.lander.mass_kg, self.base_params.gravity_m_s2)
        if self.domain_randomization is not None:
            drawn, loads = self.domain_randomization.sample(
                self.scenario.rig_params(self.base_params), scenario.loads_kg, rng
            )
            params = apply_imperfections(drawn, self.imperfections)
            steps = tuple(LoadStep(mass, step.height_m) for mass, step in zip(loads, scenario.loads, strict=True))
            scenario = replace(scenario, loads=steps)
        height = scenario.descent_height_m
        if self.reset_noise_scale > 0:
            height += rng.uniform(-self.reset_noise_scale, self.reset_noise_scale)
        drift = params.drift
        rate = rng.uniform(-1.0, 1.0) * drift.max_temperature_rate_k_per_s if self.imperfections.balancer_drift else 0.0
        return params, scenario, height, rate

    def step(self, action):
        episode = self._episode
        if episode is None:
            raise ResetNeeded("call reset() before step()")
        value = _check_action(action)
        if self._base is not None:
            self._base.setpoint_m = value * self.residual_limit_m
        total, periods, reason, truncated = 0.0, 0, None, False
        for _ in range(self.decision_period):
            if self._base is None:
                command = value * MAX_SPEED_M_S
            else:
                command = float(self._base(self._observation, self._info_now)[0]) * MAX_SPEED_M_S
                episode["base_command"] = command
            reason = self._control_period(command)
            episode["previous_action"] = value
            self._observation = self._sense()
            self._info_now = self._info(reason)
            total, periods = total + self._info_now["reward_x"], periods + 1
            truncated = reason is None and episode["steps"] >= episode["max_steps"]
            if self.render_mode == "human" and episode["steps"] % self._human_every == 0:
                self.render()
            if reason is not None or truncated:
                break
        return self._observation, total / periods, reason is not None, truncated, self._info_now

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to gym.make")
            return None
        if self._renderer is None:
            from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

            width, height = self._render_size
            self._renderer = MujocoRenderer(
                self.model, self.data, width=width, height=height, camera_name=self._camera_name
            )
        return self._renderer.render(self.render_mode)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict[str, Any]:
        """The whole environment, episode included (model, data, generator), but no renderer."""
        state = self.__dict__.copy()
        state["_renderer"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.rig.model = self.model  # one model for the rig and the environment, as built

    # -- internals ---------------------------------------------------------------------------

    def _control_period(self, command_m_s: float) -> str | None:
        """Advance one control period with the drive taking ``command_m_s`` (after the delay, if on);
        returns a termination reason, if any (the period's reward is its info's ``reward_x``)."""
        episode, data, rig = self._episode, self.data, self.rig
        command = min(max(command_m_s, -MAX_SPEED_M_S), MAX_SPEED_M_S)
        if self.imperfections.control_delay:
            command, episode["pending_command"] = episode["pending_command"], command
        episode["command"] = command
        data.qfrc_applied[self._drift_dof] = episode["drift_n_per_s"] * data.time
        episode["position_ref"] = rig.drive(data, episode["position_ref"], command * rig.gear, self.frame_skip)
        episode["steps"] += 1
        if episode["next_load"] < len(self.active_scenario.loads):
            self._place_due_loads(rig.foot_height(data))
        return self._termination_reason()

    def _place_due_loads(self, height: float) -> None:
        episode, scenario = self._episode, self.active_scenario
        due = scenario.loads_due(height, episode["next_load"])
        if due != episode["next_load"]:
            episode["next_load"] = due
            self.rig.place_loads(np.arange(len(scenario.loads)) < due)
            # The compensation error is measured against the weight placed (the first before any is).
            reference_load = max(self.rig.placed_load_kg, scenario.loads[0].mass_kg)
            episode["reference_weight_n"] = reference_load * self.params.gravity_m_s2

    def _support_force_deviation(self) -> float:
        """Support force on the lander minus its balanced value: -k x, plus balancer drift when
        the balancer acts on the lander, N."""
        data, rig = self.data, self.rig
        deviation = -self._episode["x_stiffness"] * data.qpos[rig.qzs_qpos]
        if self._drift_dof == rig.qzs_dof:
            deviation += data.qfrc_applied[rig.qzs_dof]
        return float(deviation)

    def _termination_reason(self) -> str | None:
        data, rig = self.data, self.rig
        if abs(data.qpos[rig.qzs_qpos]) >= self._x_limit:
            return "guide_stroke_limit"
        if not self._screw_limits[0] < data.qpos[rig.screw_qpos] < self._screw_limits[1]:
            return "screw_stroke_limit"
        if rig.foot_height(data) <= self._floor:
            return "pad_bottomed_out"
        return None

    def _sense(self) -> np.ndarray:
        """Read the sensors (noise, quantisation, rates by backward difference) as an observation."""
        data, rig, episode = self.data, self.rig, self._episode
        truth = self._truth
        truth[0, 0] = data.qpos[rig.qzs_qpos]
        truth[1, 0] = data.qpos[rig.screw_qpos]
        truth[2, 0] = data.sensordata[self._accel_adr] - self.params.gravity_m_s2
        truth[3, 0] = data.sensordata[self._force_adr]
        readings = self._sensors.read(self.np_random, truth)
        rates = backward_difference(readings[:2], episode["last_readings"], self.control_period_s)
        episode["last_readings"] = readings[:2].copy()
        raw = self._raw_observation
        raw[0], raw[1], raw[2], raw[3] = readings[0, 0], rates[0, 0], readings[1, 0], rates[1, 0]
        raw[4], raw[5], raw[6] = readings[2, 0], readings[3, 0], readings[1, 0] + readings[0, 0]
        raw[7], raw[8], raw[9] = rig.placed_load_kg, episode["previous_action"], episode["base_command"]
        return (raw / SCALES).astype(np.float32)

    def _info(self, reason: str | None) -> dict[str, Any]:
        data, rig, episode = self.data, self.rig, self._episode
        x = float(data.qpos[rig.qzs_qpos])
        deviation = self._support_force_deviation()
        return {
            "time_s": float(data.time),
            "x_m": x,
            "foot_height_m": rig.foot_height(data),
            "lander_velocity_m_s": rig.lander_velocity(data),
            "lander_accel_m_s2": float(data.qacc[rig.screw_dof] + data.qacc[rig.qzs_dof]),
            "support_position_m": float(data.qpos[rig.screw_qpos]),
            "support_velocity_m_s": float(data.qvel[rig.screw_dof]),
            "support_force_deviation_n": deviation,
            "pad_force_n": float(data.sensordata[self._force_adr]),
            "placed_load_kg": rig.placed_load_kg,
            "stage": episode["next_load"] - 1,
            "command_m_s": episode["command"],
            "setpoint_m": self._base.setpoint_m if self._base is not None else 0.0,
            "servo_torque_n_m": float(data.actuator_force[0]),
            "compensation_error": deviation / episode["reference_weight_n"],
            "reward_x": x_reward(x, self.reward_scale_m, self._x_limit),
            "termination_reason": reason,
        }


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


def _randomization(value: DomainRandomization | Mapping | bool | None) -> DomainRandomization | None:
    if value is None or value is False:
        return None
    if value is True:
        return DomainRandomization()
    if isinstance(value, Mapping):
        return DomainRandomization(**value)
    return validate.instance("domain_randomization", value, DomainRandomization)


def _check_control_period(control_period_s: float, physics_step_s: float) -> float:
    low, high = CONTROL_PERIOD_RANGE_S
    period = validate.positive("control_period_s", control_period_s, "s")
    if not low - 1e-12 <= period <= high + 1e-12:
        raise ValueError(
            f"control_period_s must be in [{low:g}, {high:g}] s (the RTX timer's 100 us to 10 ms), "
            f"got {control_period_s!r}"
        )
    steps = period / physics_step_s
    if abs(steps - round(steps)) > 1e-6 * steps:
        raise ValueError(
            f"control_period_s {control_period_s!r} s must be a whole number of physics steps of {physics_step_s:g} s"
        )
    return period


def _check_reset_noise(reset_noise_scale: float, scenario: Scenario) -> float:
    """The start-height perturbation must keep the start clear of the pad and of every switch height."""
    noise = validate.non_negative("reset_noise_scale", reset_noise_scale, "m")
    room = scenario.descent_height_m - max(scenario.lowest_switch_height_m, 0.0) - START_CLEARANCE_M
    if noise > 0 and noise > room:
        raise ValueError(
            f"reset_noise_scale {reset_noise_scale!r} m would start the foot below "
            f"{max(scenario.lowest_switch_height_m, 0.0) * 1e3:g} mm + 1 mm (the pad or a load's switch height); "
            f"at most {max(room, 0.0):.4g} m for {scenario.name}"
        )
    return noise


def _check_display() -> None:
    """Human rendering opens a GLFW window; without a display GLFW aborts the whole process."""
    headless = os.environ.get("MUJOCO_GL", "glfw").lower() in {"egl", "osmesa"}
    no_display = sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )
    if headless or no_display:
        raise RuntimeError(
            "render_mode='human' needs a display (DISPLAY is not set or MUJOCO_GL is egl/osmesa); "
            "use render_mode='rgb_array' with MUJOCO_GL=egl or osmesa"
        )


def _check_action(action) -> float:
    """The action as a float in [-1, 1]; NaN, infinite, non-numeric or wrongly shaped actions raise."""
    array = np.asarray(action)
    if array.dtype.kind not in "fiu":  # not bool, complex, string or object
        raise ValueError(f"action must be a real-valued array of shape (1,), got {action!r}")
    if array.shape != (1,):
        raise ValueError(f"action must have shape (1,), got shape {array.shape}")
    value = float(array[0])
    if not math.isfinite(value):
        raise ValueError(f"action must be finite, got {value!r}")
    return min(max(value, -1.0), 1.0)  # out-of-range actions are clipped to the drive's range
