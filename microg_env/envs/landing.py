"""Gymnasium environment: drive the stroke amplifier so the rig simulates microgravity."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces, utils

from microg_env import scenarios
from microg_env.imperfections import DomainRandomization, Imperfections, apply_imperfections
from microg_env.params import RigParams
from microg_env.scenarios import Scenario
from microg_env.sim.model import Rig, build_rig, flexible_unit

#: Observation entries and the scale each is divided by (SI units / scale = order one).
OBSERVATION_SCALES: dict[str, float] = {
    "x": 1e-4,  # grating ruler, m (100 um)
    "x_rate": 1e-3,  # its backward difference, m/s
    "support_position": 0.1,  # servo encoder, m above touchdown
    "support_velocity": 0.1,  # encoder backward difference, m/s
    "lander_accel": 0.1,  # accelerometer with g removed, m/s^2 (up positive)
    "pad_force": 100.0,  # pad force sensor, N
    "height": 0.1,  # foot height from encoder + ruler, m
    "placed_load": 1.0,  # test weights placed so far, kg
    "previous_action": 1.0,  # the action of the previous step
}
OBSERVATION_INDEX = {name: i for i, name in enumerate(OBSERVATION_SCALES)}
_SCALES = np.array(list(OBSERVATION_SCALES.values()))
#: Margin before a stroke end at which the episode terminates, m.
_STOP_MARGIN_M = 1e-4


class MicroGravityLandingEnv(gym.Env, utils.EzPickle):
    """
    ## Description
    The QZS microgravity simulation rig of Jia et al. (Actuators 2024, 13(9), 361), simulated in
    MuJoCo. A 620 kg lander hangs on a quasi-zero-stiffness (QZS) mechanism and a nitrogen balancer
    from a floating support, which a servo screw stage (the "stroke amplifier") moves. While the
    relative displacement x = z_lander - z_support stays at 0 the support force is constant and a
    small test weight m makes the lander fall at m g / (M + m), 1e-3 to 1e-4 g, onto a soft rubber
    pad. The agent commands the stroke amplifier; every micrometre of x it lets through is a
    36 mN force error (5.9e-6 g). Episodes follow the paper's test conditions (Table 2).

    ## Action Space
    ``Box(-1, 1, (1,), float32)``: the servo drive's speed reference for the support, scaled to
    +-1250 mm/s (the mechanism's maximum, Section 4.1), up positive. Out-of-range values are
    clipped to [-1, 1]; NaN, infinite or wrongly shaped actions raise ``ValueError``. The drive
    integrates the reference into its position reference and closes its own PI speed loop.

    ## Observation Space
    ``Box(-inf, inf, (9,), float32)``, what the rig's sensors give, each divided by a scale
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
    | 8 | previous action | - | 1 |

    ## Rewards
    ``reward = reward_compensation + reward_action_rate`` with
    ``reward_compensation = exp(-(e / compensation_scale)^2)``, e = dF / (m_ref g) the
    gravity-compensation error: dF is the deviation of the support force (QZS and balancer) from
    its balanced value, caused by x and by balancer drift, and m_ref the test weight placed (the
    first weight's before any is placed); and
    ``reward_action_rate = -action_rate_weight * (a_t - a_{t-1})^2``. A step is worth at most 1.

    ## Starting State
    Balanced at rest with the foot at the scenario's descent height (plus a uniform perturbation
    of +-``reset_noise_scale`` m), x = 0, servo holding. The scenario's first test weight is placed
    at t = 0; later ones when the foot comes down to their height (condition 3: 1 kg more at 25 mm).

    ## Episode End
    Terminated when x reaches the 50 mm guide stroke or the support the screw's 480 mm stroke
    (``info["termination_reason"]`` names which). Truncated at 30 s of simulated time by
    ``max_episode_steps`` (30000 at the default 1 kHz; pass ``max_episode_steps`` to ``gym.make``
    with another ``control_period_s``).

    ## Arguments
    ``gym.make("microg_env:MicroGravityLanding-v0", **kwargs)`` with

    | argument | default | meaning |
    |---|---|---|
    | ``condition`` | 1 | the paper's condition 1, 2 or 3 (ignored when ``scenario`` is given) |
    | ``scenario`` | None | a custom ``Scenario`` (load schedule, descent height, lander, pad) |
    | ``control_period_s`` | 1e-3 | control period: the paper's 1000, 500, 200 or 100 us, or another |
    | ``imperfections`` | ``Imperfections()`` | which non-ideal effects are on (all by default) |
    | ``domain_randomization`` | None | a ``DomainRandomization`` to perturb rig and load at each reset |
    | ``params`` | ``RigParams()`` | the rig |
    | ``xml_file`` | None | an MJCF template other than the packaged ``scene.xml`` |
    | ``compensation_scale`` | 0.05 | relative compensation error that costs a factor e in reward |
    | ``action_rate_weight`` | 0.1 | weight of the action-rate penalty |
    | ``reset_noise_scale`` | 0.0 | half-width of the start-height perturbation, m |
    | ``render_mode``, ``width``, ``height``, ``camera_name`` | None, 640, 480, "side" | rendering |

    ``info`` carries the reward terms and the true physical state: ``time_s``, ``x_m``,
    ``foot_height_m``, ``lander_velocity_m_s``, ``lander_accel_m_s2``, ``support_position_m``,
    ``support_velocity_m_s``, ``support_force_deviation_n``, ``pad_force_n``,
    ``placed_load_kg``, ``stage``, ``command_m_s``, ``servo_torque_n_m``,
    ``compensation_error``, ``reward_compensation``, ``reward_action_rate`` and
    ``termination_reason``.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 1000}

    def __init__(
        self,
        condition: int = 1,
        scenario: Scenario | None = None,
        control_period_s: float = 1e-3,
        imperfections: Imperfections | None = None,
        domain_randomization: DomainRandomization | None = None,
        params: RigParams | None = None,
        xml_file: str | None = None,
        compensation_scale: float = 0.05,
        action_rate_weight: float = 0.1,
        reset_noise_scale: float = 0.0,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera_name: str = "side",
    ) -> None:
        utils.EzPickle.__init__(
            self,
            condition,
            scenario,
            control_period_s,
            imperfections,
            domain_randomization,
            params,
            xml_file,
            compensation_scale,
            action_rate_weight,
            reset_noise_scale,
            render_mode,
            width,
            height,
            camera_name,
        )
        self.scenario = scenarios.condition(condition) if scenario is None else scenario
        if not isinstance(self.scenario, Scenario):
            raise ValueError(f"scenario must be a Scenario, got {type(self.scenario).__name__}")
        self.imperfections = Imperfections() if imperfections is None else imperfections
        if not isinstance(self.imperfections, Imperfections):
            raise ValueError(f"imperfections must be an Imperfections, got {type(self.imperfections).__name__}")
        if domain_randomization is not None and not isinstance(domain_randomization, DomainRandomization):
            raise ValueError(
                f"domain_randomization must be a DomainRandomization or None, got {domain_randomization!r}"
            )
        self.domain_randomization = domain_randomization
        self.base_params = RigParams() if params is None else params
        self.control_period_s = _positive("control_period_s", control_period_s, upper=0.01)
        self.compensation_scale = _positive("compensation_scale", compensation_scale)
        self.action_rate_weight = _non_negative("action_rate_weight", action_rate_weight)
        self.reset_noise_scale = _non_negative("reset_noise_scale", reset_noise_scale)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.render_mode = render_mode
        self.xml_file = xml_file
        self._render_size = (width, height)
        self._camera_name = camera_name
        self._renderer = None

        self.frame_skip = math.ceil(self.control_period_s / self.base_params.timestep_s - 1e-9)
        self._timestep = self.control_period_s / self.frame_skip  # the physics step divides the period
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.control_period_s)}
        self._human_every = max(1, round(1.0 / (60.0 * self.control_period_s)))

        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(len(_SCALES),), dtype=np.float32)
        self._build(self.base_params, self.scenario)

    # -- model -------------------------------------------------------------------------------

    def _build(self, params: RigParams, scenario: Scenario) -> None:
        """Compile the rig for ``scenario`` and cache what the step needs."""
        top = params.screw.range_m[1] - 0.01
        if scenario.descent_height_m + self.reset_noise_scale > top:
            raise ValueError(
                f"Scenario.descent_height_m {scenario.descent_height_m!r} m is above the screw's reach "
                f"({top:.2f} m with the reset noise)"
            )
        params = apply_imperfections(scenario.rig_params(params), self.imperfections)
        params = replace(params, timestep_s=self._timestep)
        self.params = params
        self.active_scenario = scenario
        self.rig: Rig = build_rig(params, scenario.loads_kg, xml_file=self.xml_file)
        self.model = self.rig.model
        self.data = mujoco.MjData(self.model)
        model, rig, sensors = self.model, self.rig, params.sensors
        self._accel_adr = int(model.sensor_adr[model.sensor("lander_accel").id]) + 2
        self._force_adr = int(model.sensor_adr[model.sensor("pad_force").id])
        self._encoder_step = params.screw.lead_m / params.screw.belt_ratio / sensors.encoder_counts_per_rev
        self._accel_noise = sensors.accelerometer_noise_density_m_s2_per_sqrt_hz * math.sqrt(
            0.5 / self.control_period_s
        )
        unit = flexible_unit(params)
        self._balancer_force = unit.balancer_force_n
        self._x_stiffness = unit.stiffness_n_per_m
        self._x_limit = params.qzs.stroke_m / 2.0 - _STOP_MARGIN_M
        low, high = params.screw.range_m
        self._screw_limits = (low + _STOP_MARGIN_M, high - _STOP_MARGIN_M)
        self._n_loads = len(scenario.loads)
        self._max_speed = params.screw.max_speed_m_per_s
        self._omega_per_action = self._max_speed * rig.gear
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- gymnasium API -------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        rng = self.np_random
        if self.domain_randomization is not None:
            params, scenario = self.domain_randomization.sample(self.base_params, self.scenario, rng)
            self._build(params, scenario)
        height = self.active_scenario.descent_height_m
        if self.reset_noise_scale > 0:
            height += rng.uniform(-self.reset_noise_scale, self.reset_noise_scale)
        self.rig.reset(self.data, height)
        self._next_load = 0
        self._place_due_loads(height)
        mujoco.mj_forward(self.model, self.data)
        drift = self.params.drift
        rate = rng.uniform(-1.0, 1.0) * drift.max_temperature_rate_k_per_s if self.imperfections.balancer_drift else 0.0
        self._drift_n_per_s = self._balancer_force * rate / drift.gas_temperature_k
        self._previous_action = 0.0
        self._position_ref = float(self.data.ctrl[0])
        self._steps = 0
        self._last_ruler = self._last_encoder = None
        obs = self._sense()
        if self.render_mode == "human":
            self.render()
        return obs, self._info(0.0, self._support_force_deviation(), 0.0, 0.0, 0.0, None)

    def step(self, action):
        value = _check_action(action)
        data, rig = self.data, self.rig
        command = self._previous_action if self.imperfections.control_delay else value
        omega = command * self._omega_per_action
        self._position_ref += omega * self.control_period_s
        data.ctrl[0] = self._position_ref - 0.5 * omega * self.control_period_s  # the period's mean
        data.ctrl[1] = omega
        data.qfrc_applied[rig.qzs_dof] = self._drift_n_per_s * data.time
        mujoco.mj_step(self.model, data, nstep=self.frame_skip)
        self._steps += 1
        if self._next_load < self._n_loads:
            self._place_due_loads(rig.foot_height(data))

        reward_action_rate = -self.action_rate_weight * (value - self._previous_action) ** 2
        self._previous_action = value
        obs = self._sense()
        deviation = self._support_force_deviation()
        error = deviation / self._reference_weight_n
        reward_compensation = math.exp(-((error / self.compensation_scale) ** 2))
        x = data.qpos[rig.qzs_qpos]
        reason = None
        if abs(x) >= self._x_limit:
            reason = "guide_stroke_limit"
        elif not self._screw_limits[0] < data.qpos[rig.screw_qpos] < self._screw_limits[1]:
            reason = "screw_stroke_limit"
        info = self._info(command * self._max_speed, deviation, error, reward_compensation, reward_action_rate, reason)
        if self.render_mode == "human" and self._steps % self._human_every == 0:
            self.render()
        return obs, reward_compensation + reward_action_rate, reason is not None, False, info

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

    # -- internals ---------------------------------------------------------------------------

    def _place_due_loads(self, height: float) -> None:
        due = self.active_scenario.loads_due(height, self._next_load)
        if due != self._next_load:
            self._next_load = due
            self.rig.place_loads(np.arange(self._n_loads) < due)
            # The compensation error is measured against the weight placed (the first before any is).
            reference_load = max(self.rig.placed_load_kg, self.active_scenario.loads[0].mass_kg)
            self._reference_weight_n = reference_load * self.params.gravity_m_s2

    def _support_force_deviation(self) -> float:
        """Support force on the lander minus its balanced value: -k x plus balancer drift, N."""
        data = self.data
        return float(-self._x_stiffness * data.qpos[self.rig.qzs_qpos] + data.qfrc_applied[self.rig.qzs_dof])

    def _sense(self) -> np.ndarray:
        """Read the sensors (noise, quantisation, rates by backward difference) as an observation."""
        data, sensors, period = self.data, self.params.sensors, self.control_period_s
        ruler = data.qpos[self.rig.qzs_qpos]
        encoder = data.qpos[self.rig.screw_qpos]
        accel = data.sensordata[self._accel_adr] - self.params.gravity_m_s2
        force = data.sensordata[self._force_adr]
        if self.imperfections.sensor_noise:
            noise = self.np_random.standard_normal(3)
            step = sensors.ruler_resolution_m
            ruler = round((ruler + sensors.ruler_noise_m * noise[0]) / step) * step
            encoder = round(encoder / self._encoder_step) * self._encoder_step
            accel += self._accel_noise * noise[1]
            force += sensors.force_noise_n * noise[2]
        if self._last_ruler is None:
            x_rate = support_velocity = 0.0
        else:
            x_rate = (ruler - self._last_ruler) / period
            support_velocity = (encoder - self._last_encoder) / period
        self._last_ruler, self._last_encoder = ruler, encoder
        raw = (
            ruler,
            x_rate,
            encoder,
            support_velocity,
            accel,
            force,
            encoder + ruler,
            self.rig.placed_load_kg,
            self._previous_action,
        )
        return (np.array(raw) / _SCALES).astype(np.float32)

    def _info(
        self,
        command: float,
        deviation: float,
        error: float,
        reward_compensation: float,
        reward_action_rate: float,
        reason: str | None,
    ) -> dict[str, Any]:
        data, rig = self.data, self.rig
        return {
            "time_s": float(data.time),
            "x_m": float(data.qpos[rig.qzs_qpos]),
            "foot_height_m": rig.foot_height(data),
            "lander_velocity_m_s": rig.lander_velocity(data),
            "lander_accel_m_s2": float(data.qacc[rig.screw_dof] + data.qacc[rig.qzs_dof]),
            "support_position_m": float(data.qpos[rig.screw_qpos]),
            "support_velocity_m_s": float(data.qvel[rig.screw_dof]),
            "support_force_deviation_n": deviation,
            "pad_force_n": float(data.sensordata[self._force_adr]),
            "placed_load_kg": rig.placed_load_kg,
            "stage": self._next_load - 1,
            "command_m_s": command,
            "servo_torque_n_m": float(data.actuator_force[0]),
            "compensation_error": float(error),
            "reward_compensation": reward_compensation,
            "reward_action_rate": reward_action_rate,
            "termination_reason": reason,
        }


def _positive(name: str, value: float, upper: float = math.inf) -> float:
    if not (isinstance(value, int | float) and math.isfinite(value) and 0 < value <= upper):
        bound = "" if math.isinf(upper) else f" and at most {upper:g}"
        raise ValueError(f"{name} must be positive{bound}, got {value!r}")
    return float(value)


def _non_negative(name: str, value: float) -> float:
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return float(value)


def _check_action(action) -> float:
    """The action as a float in [-1, 1]; NaN, infinite or wrongly shaped actions raise."""
    array = np.asarray(action, dtype=np.float64)
    if array.shape != (1,):
        raise ValueError(f"action must have shape (1,), got shape {array.shape}")
    value = float(array[0])
    if not math.isfinite(value):
        raise ValueError(f"action must be finite, got {value!r}")
    return min(max(value, -1.0), 1.0)  # out-of-range actions are clipped to the drive's range
