"""Where the sub-micrometre metrics' physics-step error comes from: the timing of the drive's
inputs and output against the mechanics (#47).

MuJoCo 4.0 integrates the ``dcmotor``'s current filter and LuGre bristles exactly over a step for
the inputs it holds (zero-order hold). What remains first order in the step is *when* the drive
reads the mechanics and when the mechanics feel the drive. Each ``--scheme`` changes one of these
on the single environment, every other element as shipped:

- ``shipped``: the current at the step's end drives the step (MuJoCo's ``actearly``, on for a
  ``dcmotor``); the speed loop's position reference is the ramp's value at the step's end.
- ``late-current``: ``actearly`` off: the current at the step's start drives the step.
- ``start-reference``: ``late-current``, and the reference is the ramp's value at the step's start,
  like the encoder angle it is compared with (the speed input less h/Ti of itself).
- ``midpoint``: ``late-current``, and the speed loop reads the reference, angle and speed at the
  middle of the step the current is filtered over (a per-step prediction from the last step's
  acceleration); with ``--integrator euler`` this is the environment's ``drive_scheme="midpoint"``
  but for the guide friction's ``actearly``, which this script turns off too (1e-9 relative).
- ``midpoint-speed``: ``midpoint`` without the acceleration term.

``--overrides`` switches elements off for an ablation (a controller knows them, as in
``benchmarks/convergence.py``); ``--own-friction`` takes the motor's and the guide's LuGre laws out
of MuJoCo and integrates them per step from the step's middle speed; ``--integrator`` swaps
MuJoCo's integrator. Prints x in free fall and at the collision (max |x|, µm) at each
step and each value's change from the coarsest step to the finest.

Run: ``python research/drive_timing.py [--scheme start-reference] [--controllers adaptive-dither]
[--conditions 1,2,3] [--steps-us 100 25] [--overrides '{"servo.bristle_stiffness_n_m_per_rad": 0}']
[--own-friction] [--integrator implicit]``.
The findings are in docs/research-log.md ("0.21.0: the physics step's error ...").
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import mujoco

from microg_env.controllers import make_controller
from microg_env.envs import core
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.params import RigParams, with_overrides
from microg_env.rollout.episode import run_with_metrics
from microg_env.sim.physics import ModelPhysics

SCHEMES = ("shipped", "late-current", "start-reference", "midpoint", "midpoint-speed")
INTEGRATORS = {
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
#: The dcmotor's PI gains in ``actuator_gainprm``: kp (position) and kd (speed); kp / kd = 1 / Ti.
KP_INDEX, KD_INDEX = 4, 6
#: A dcmotor's LuGre law: bristle stiffness and damping in ``actuator_dynprm``, Coulomb and static
#: friction and Stribeck speed in ``actuator_biasprm``.
SIGMA0, SIGMA1, COULOMB, STATIC, STRIBECK = 5, 6, 3, 4, 5
FRICTION_ACTUATORS = ("servo", "guide_friction")


class LuGre:
    """One actuator's LuGre law, out of MuJoCo (its Coulomb and static friction set to 0, which
    keeps its bristle at 0) and integrated here: the force at a step's start from the speed there,
    the bristle over the step exactly for the step's middle speed."""

    def __init__(self, model: mujoco.MjModel, name: str) -> None:
        self.id = model.actuator(name).id
        dyn, bias = model.actuator_dynprm[self.id], model.actuator_biasprm[self.id]
        self.sigma0, self.sigma1 = dyn[SIGMA0], dyn[SIGMA1]
        self.coulomb, self.static, self.stribeck = bias[COULOMB], bias[STATIC], bias[STRIBECK]
        bias[COULOMB] = bias[STATIC] = 0.0
        self.gear = model.actuator_gear[self.id, 0]
        self.dof = model.jnt_dofadr[model.actuator_trnid[self.id, 0]]
        self.bristle, self.previous, self.middle = 0.0, None, 0.0

    def level(self, speed: float) -> float:
        return self.coulomb + (self.static - self.coulomb) * math.exp(-((speed / self.stribeck) ** 2))

    def force(self, data: mujoco.MjData, h: float) -> float:
        """The generalised force over the coming step; remembers the step's middle speed."""
        speed = data.qvel[self.dof] * self.gear  # now (actuator_velocity is the last step's)
        acceleration = 0.0 if self.previous is None else (speed - self.previous) / h
        self.previous, self.middle = speed, speed + h * acceleration
        start = speed + 0.5 * h * acceleration
        rate = start - self.sigma0 * abs(start) * self.bristle / self.level(start)
        return -(self.sigma0 * self.bristle + self.sigma1 * rate) * self.gear

    def advance(self, h: float) -> None:
        decay = -self.sigma0 * abs(self.middle) / self.level(self.middle)
        grow = math.exp(decay * h)
        self.bristle = grow * self.bristle + ((grow - 1.0) / decay if decay else h) * self.middle


class TimedPhysics(ModelPhysics):
    """One rig stepped one physics step at a time, its drive's speed input set per ``scheme``."""

    scheme = "shipped"
    own_friction = False

    def step(self, ids, nstep: int) -> None:
        model, data = self.model, self.data
        if self.own_friction and not hasattr(self, "friction"):  # after the reset wrote the episode's laws
            self.friction = [LuGre(model, name) for name in FRICTION_ACTUATORS]
        applied = data.qfrc_applied.copy()  # the balancer's drift, set per period
        servo = model.actuator("servo").id
        h = model.opt.timestep
        inverse_ti = model.actuator_gainprm[servo, KP_INDEX] / model.actuator_gainprm[servo, KD_INDEX]
        dof, gear = model.jnt_dofadr[model.actuator_trnid[servo, 0]], model.actuator_gear[servo, 0]
        speed_ref = data.ctrl[1]  # the period's commanded speed, rad/s (the drive kernel set it)
        previous = getattr(self, "_previous_speed", None)
        for _ in range(nstep):
            speed = data.qvel[dof] * gear  # now (actuator_velocity is the last step's)
            acceleration = 0.0 if previous is None else (speed - previous) / h
            if self.scheme == "start-reference":
                # kp (r_end - theta) + kd (w_ref' - w) = kp (r_start - theta) + kd (w_ref - w)
                data.ctrl[1] = speed_ref * (1.0 - h * inverse_ti)
            elif self.scheme == "midpoint-speed":  # the middle's angle and reference, the start's speed
                data.ctrl[1] = speed_ref - 0.5 * h * inverse_ti * (speed_ref + speed)
            elif self.scheme == "midpoint":
                middle = speed + h * acceleration  # the speed over the step, as the next step has it
                data.ctrl[1] = speed_ref - 0.5 * h * inverse_ti * (speed_ref + middle) - h * acceleration
            data.qfrc_applied[:] = applied
            for law in getattr(self, "friction", ()):
                data.qfrc_applied[law.dof] += law.force(data, h)
            mujoco.mj_step(model, data)
            for law in getattr(self, "friction", ()):
                law.advance(h)
            previous = speed
        self._previous_speed = previous
        data.ctrl[1] = speed_ref
        data.qfrc_applied[:] = applied


def run(controller: str, condition: int, step_us: float, args: argparse.Namespace) -> tuple[float, float]:
    """x in free fall and at the collision, µm, of one condition under ``args``' scheme."""
    scheme = args.scheme
    params = with_overrides(RigParams(), args.overrides)
    env = MicroGravityLandingEnv(  # MuJoCo's own stepping: the probe's schemes replace it per step
        condition=condition, physics_step_s=step_us / 1e6, params=params, drive_scheme="mujoco"
    )
    lander = env.unwrapped.core
    model = lander.rig.model
    model.actuator_actearly[:] = scheme == "shipped"
    model.opt.integrator = INTEGRATORS[args.integrator]
    lander.physics.__class__ = TimedPhysics
    lander.physics.scheme = scheme
    lander.physics.own_friction = args.own_friction
    metrics = run_with_metrics(env, make_controller(controller, env.settings.control_period_s, params), seed=0,
                               duration_s=args.duration)[2]  # fmt: skip
    return metrics.flexible_unit_excursion_free_fall_m * 1e6, metrics.flexible_unit_excursion_collision_m * 1e6


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scheme", choices=SCHEMES, default="start-reference")
    parser.add_argument("--controllers", default="pid,feedforward,adaptive-dither,residual-sac-setpoint")
    parser.add_argument("--conditions", default="1,2,3")
    parser.add_argument("--steps-us", type=float, nargs="+", default=[100.0, 25.0])
    parser.add_argument("--overrides", type=json.loads, default={})
    parser.add_argument("--duration", type=float, default=None, help="simulated s per run (default: 30)")
    parser.add_argument("--own-friction", action="store_true", help="the LuGre laws integrated per step here")
    parser.add_argument("--integrator", choices=tuple(INTEGRATORS), default="implicitfast")
    args = parser.parse_args(argv)
    core.mj_step = None  # the PID's compiled loop steps MuJoCo itself: every controller through TimedPhysics
    print(f"scheme {args.scheme}; x in um at each step; change from {args.steps_us[0]:g} to {args.steps_us[-1]:g} us")
    for controller in args.controllers.split(","):
        for condition in map(int, args.conditions.split(",")):
            runs = [run(controller, condition, s, args) for s in args.steps_us]
            cells = "  ".join(f"{free:.4f}/{collision:.4f}" for free, collision in runs)
            (free0, col0), (free1, col1) = runs[0], runs[-1]
            print(f"{controller:<22} c{condition}  {cells}  free fall {100 * (free0 / free1 - 1):+.1f} %,"
                  f" collision {100 * (col0 / col1 - 1):+.1f} %", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
