"""Gymnasium environment: drive the stroke amplifier so the rig simulates microgravity."""

from __future__ import annotations

import math
import os
import sys
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.error import ResetNeeded

from microg_env import validate
from microg_env.envs.core import SCORE_KEY, STATE_KEYS, TERMINATION_REASONS, LandingCore, check_actions
from microg_env.envs.period import x_reward
from microg_env.interface import (
    OBSERVATION_INDEX,
    OBSERVATION_SCALES,
    action_space,
    observation_space,
)
from microg_env.params import RigParams
from microg_env.scenarios import Scenario
from microg_env.task import TaskSettings

__all__ = ["OBSERVATION_INDEX", "OBSERVATION_SCALES", "MicroGravityLandingEnv", "x_reward"]

#: Largest render size, pixels (MuJoCo's offscreen buffer is set by the model's offwidth/offheight).
MAX_RENDER_PIXELS = 8192
#: The one rig of the single environment, as the core's rig indices.
_ONE = np.zeros(1, dtype=np.int64)


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
    ``Box(-1, 1, (1,), float32)`` (``(3,)`` in gains mode), held for ``decision_period`` control periods:

    * ``action_mode="speed"`` (default): the servo drive's speed reference for the support, scaled
      to +-``speed_limit_m_s`` (by default 1250 mm/s, the mechanism's maximum, Section 4.1), up
      positive;
    * ``action_mode="residual"``: a setpoint for x, scaled to +-``residual_limit_m`` (1 um), on a
      base controller (``base_controller``: ``pid``, ``pid-dom``, ``feedforward``, ``adaptive``,
      ``adaptive-dither``, ``adaptive-friction`` or ``oracle``, which is told each episode's plant) that commands the
      drive every control period from the latest observation. An action of 0 is the base controller.
      With ``residual_highpass_hz`` the setpoint is the action high-passed
      (:func:`~microg_env.interface.residual_setpoint`): a held action decays to 0, and with
      ``residual_highpass_order=2`` a steadily changing one as well. With ``residual_gate_m`` the
      action acts only at decisions whose foot reading (encoder + ruler) is at most that high
      above the pad, else it is taken as 0 (:func:`~microg_env.interface.gated_actions`): at 0 m
      the base controller alone flies every free fall and the residual shapes the collision. The
      gate passes the action, then high-passed (``residual_gate_on="action"``: an action held
      before the gate opens enters as a step), or the high-passed setpoint (``"setpoint"``: the
      action is filtered throughout, and only what it changes passes when the gate opens);
    * ``action_mode="gains"``: multipliers ``gain_limit ** action`` (x1/2 to x2) of the Kp, Ki and Kd
      of a base PID (``pid`` or ``pid-dom``) that commands the drive every control period, gated as a
      residual is by ``residual_gate_m`` (the PID as tuned above it); an action of 0 is the PID as
      tuned (the paper's Conclusions: learning that adjusts the control parameters during the
      collision).

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
    | 8 | the agent's previous action (gains mode: the mean of its three numbers) | - | 1 |
    | 9 | the base controller's speed command (residual and gains mode; 0 otherwise) | - | 1.25 m/s |

    ## Rewards
    Per control period, ``x_reward(x) = 1 - log(1 + (x/x0)^2) / log(1 + (x_max/x0)^2)`` with x the
    true relative displacement, x0 = ``reward_scale_m`` (10 nm, twice the ruler's step) and x_max
    the guide's half stroke less the stop margin, 24.9 mm, where the episode ends: it falls by the
    same amount for every decade of x, from nanometres to millimetres, and lies in [0, 1].
    ``info["reward_x"]`` holds it. With ``reward_descent_weight`` w > 0 (default 0) the period's
    reward is ``(1 - w) x_reward(x) + w d``: d scores, in decades as x is (from
    ``reward_descent_scale_m_s``, 0.1 um/s, to 10 mm/s, floored at 0), the descent's velocity error
    ``info["descent_velocity_error_m_s"]`` = v(t) - v(t0) - a_ideal (t - t0), the compensation
    error integrated over each stage's descent from 0.2 s after its weight is placed (t0) to the
    first pad contact (0, d = 1, outside it). A step's reward is its mean over the control periods
    it spans. Never negative, it never makes ending an episode pay.

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
    ``gym.make("microg_env:MicroGravityLanding-v1", **kwargs)``: the keywords are the fields of
    :class:`~microg_env.task.TaskSettings`, which owns their defaults (``TaskSettings()``
    shows them), plus rendering's:

    | argument | meaning |
    |---|---|
    | ``condition`` | the paper's condition 1, 2 or 3 (unless ``scenario`` or ``scenario_sampler`` is given) |
    | ``scenario`` | a custom ``Scenario`` (load schedule, descent height, duration, overrides) |
    | ``scenario_sampler`` | a ``ScenarioSampler`` ("training", or its fields as a dict): a schedule per reset |
    | ``control_period_s`` | control period: the paper's 1000, 500, 200 or 100 us, up to 10 ms |
    | ``physics_step_s`` | physics step; it must divide the control period |
    | ``drive_scheme`` | ``"midpoint"`` (default: the drive's inputs at the step's middle) or ``"mujoco"`` |
    | ``decision_period`` | control periods an action is held (the base controller still runs every one) |
    | ``action_mode`` | ``"speed"``, ``"residual"`` or ``"gains"`` (see Action Space) |
    | ``base_controller`` | the controller a residual action moves the setpoint of, or a gains action's PID |
    | ``residual_limit_m`` | the setpoint an action of +-1 stands for, m |
    | ``residual_highpass_hz`` | corner of the residual's high-pass, Hz (0: none) |
    | ``residual_highpass_order`` | its first-order stages in cascade: 1 or 2 (none without a corner) |
    | ``residual_gate_m`` | foot height at or below which the residual or gains action acts, m (None: always) |
    | ``residual_gate_on`` | what the gate passes: ``"action"`` (then high-passed) or the high-passed ``"setpoint"`` |
    | ``gain_limit`` | the gain multiplier an action of +1 stands for (-1: its inverse), in (1, 10] |
    | ``speed_limit_m_s`` | the speed a speed action of +1 stands for, m/s: 0.001 to 1.25 (the default) |
    | ``imperfections`` | which non-ideal effects are on (or their flags as a dict) |
    | ``domain_randomization`` | ``DomainRandomization``; ``True``, ``"full"``, ``"wider"``: its presets |
    | ``sensor_set`` | ``"paper"``: ruler and encoder only (pad force, accelerometer read 0); ``"mixed"``: drawn |
    | ``hidden_observations`` | observation entries the agent is shown as 0 (a residual's base reads them) |
    | ``params`` | the rig: ``RigParams`` (``load_rig`` reads a rig file) or overrides by dotted path |
    | ``xml_file`` | an MJCF template other than the packaged ``scene.xml`` |
    | ``reward_scale_m`` | x0 of the reward, m |
    | ``reward_descent_weight`` | the reward's share paid for the descent's velocity error (see Rewards) |
    | ``reward_descent_scale_m_s`` | the velocity error that term counts from, m/s |
    | ``reset_noise_scale`` | half-width of the start-height perturbation, m |
    | ``render_mode``, ``width``, ``height``, ``camera_name`` | rendering (None, 640, 480, "side") |

    ``info`` carries the reward and the true physical state: ``time_s``, ``x_m``,
    ``foot_height_m``, ``lander_velocity_m_s``, ``lander_accel_m_s2``, ``accelerometer_m_s2`` (what
    the accelerometer reads), ``support_position_m``, ``support_velocity_m_s``,
    ``support_force_deviation_n``, ``pad_force_n``, ``placed_load_kg``, ``stage``, ``command_m_s``
    (the speed command the drive received), ``setpoint_m``, ``servo_torque_n_m``,
    ``compensation_error``, ``reward_x``, ``descent_velocity_error_m_s``, ``termination_reason``
    and ``sensor_set`` (the episode's: with ``sensor_set="mixed"``, the one drawn).

    Copies (``pickle``, ``cloudpickle``, ``copy.deepcopy``) carry the episode: a copy made mid-episode
    continues exactly as the original would.

    The environment is the one-rig case of :class:`~microg_env.envs.core.LandingCore`; the vector
    environment (``gym.make_vec(..., vectorization_mode="vector_entry_point")``,
    :class:`~microg_env.envs.vector.MicroGravityLandingVectorEnv`) steps N rigs of the same core on
    ``mujoco.batch`` and gives rig i seeded s exactly this environment's episode seeded s.

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
        *,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera_name: str = "side",
        **settings: Any,
    ) -> None:
        if render_mode is not None:
            validate.choice("render_mode", render_mode, tuple(self.metadata["render_modes"]))
        if render_mode == "human":
            _check_display()
        self.render_mode = render_mode
        self._renderer = None
        self.core = LandingCore(1, TaskSettings(**settings))
        core = self.core
        self.settings = core.settings
        self.scenario, self.base_params = core.scenario, core.base_params
        self.rig = core.rig
        #: Simulated seconds one ``step`` advances: the control period times the decision period.
        self.dt = self.settings.control_period_s * self.settings.decision_period
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.dt)}  # frames play in real time
        self._human_every = max(1, round(1.0 / (60.0 * self.dt)))
        self.action_space = action_space(self.settings.action_mode)
        self.observation_space = observation_space()
        self._render_size, self._camera_name = render_settings(self.model, render_mode, width, height, camera_name)

    # -- the rig as it is now ------------------------------------------------------------------

    @property
    def model(self):
        """The compiled rig model (its field values are the current episode's)."""
        return self.core.physics.model

    @property
    def data(self):
        """The rig's ``MjData``."""
        return self.core.physics.data

    @property
    def params(self) -> RigParams:
        """The episode's rig (a draw of the domain randomisation, if any); before a reset, the nominal one."""
        episode = self.core.episodes[0]
        return self.core.nominal_params if episode is None else episode.params

    @property
    def active_scenario(self) -> Scenario:
        """The episode's schedule (drawn, with the drawn test weights); before a reset, the scenario."""
        episode = self.core.episodes[0]
        return self.scenario if episode is None else episode.scenario

    # -- gymnasium API -------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            seed = validate.integer("seed", seed, 0)  # a plain int (Gymnasium refuses NumPy integers)
        generator = (self._np_random, self._np_random_seed)
        try:
            super().reset(seed=seed)
            self.core.reset(_ONE, [self.np_random])  # draws and checks before it writes
        except BaseException:  # a failed reset leaves the environment exactly as it was
            self._np_random, self._np_random_seed = generator
            raise
        info = self._info(np.zeros(1, dtype=np.int64))
        if self.render_mode == "human":
            self.render()
        return self.core.shown()[0], info

    def step(self, action):
        core = self.core
        if core.episodes[0] is None:
            raise ResetNeeded("call reset() before step()")
        actions = check_actions(action, self.action_space.shape)
        before = int(core.steps[0]) // self._human_every if self.render_mode == "human" else None
        reward, codes, truncated, _ = core.step(_ONE, actions, [self.np_random])
        if before is not None and before != int(core.steps[0]) // self._human_every:
            self.render()
        observation, info = core.shown()[0], self._info(codes)
        if core.score is not None and (codes[0] or truncated[0]):
            score = float(core.scores(_ONE, codes, truncated)[0])
            if not math.isnan(score):  # the episode ended by itself, not at a step limit
                info[SCORE_KEY] = score
        return observation, float(reward[0]), bool(codes[0]), bool(truncated[0]), info

    def _info(self, codes: np.ndarray) -> dict[str, Any]:
        info = dict(zip(STATE_KEYS, self.core.state(_ONE)[0].tolist(), strict=True))  # plain floats
        info["stage"] = int(info["stage"])
        info["termination_reason"] = TERMINATION_REASONS[codes[0]]
        info["sensor_set"] = self.core.episodes[0].sensor_set
        return info

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


def render_settings(
    model, render_mode: str | None, width: int, height: int, camera_name: str
) -> tuple[tuple[int, int], str]:
    """The checked (width, height) and camera of a rendering of ``model``: a size in pixels that,
    offscreen, fits its offscreen buffer, and one of its cameras."""
    size = (
        validate.integer("width", width, 1, MAX_RENDER_PIXELS),
        validate.integer("height", height, 1, MAX_RENDER_PIXELS),
    )
    validate.instance("camera_name", camera_name, str)
    if camera_name not in {model.camera(i).name for i in range(model.ncam)}:
        cameras = ", ".join(model.camera(i).name for i in range(model.ncam))
        raise ValueError(f"camera_name must be one of the model's cameras ({cameras}), got {camera_name!r}")
    if render_mode == "rgb_array":
        offscreen = (model.vis.global_.offwidth, model.vis.global_.offheight)
        for name, pixels, most in zip(("width", "height"), size, offscreen, strict=True):
            validate.integer(name, pixels, 1, most)
    return size, camera_name


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
