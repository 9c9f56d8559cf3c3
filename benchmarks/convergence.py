"""Convergence of every reported metric with the physics step.

Runs the paper's three conditions with each controller (the tuned PID, the feed-forward and the
shipped residual policy), every imperfection on, seed 0, at a range of physics steps, and compares
each metric with its value at a step four times finer than the candidate. A step converges when
every metric is within 1 % of that finer value and every compensation error within 0.02
percentage points (the criterion of the fidelity review).

The study behind the default PHYSICS_STEP_S and what docs/model.md ("Physics step") says of it:
Under the midpoint drive 100 us converges within 1 % for the classical controllers' excursions,
every compensation error and the landing; the adaptive ones' free fall (3 %), the learned policy's
single episodes and the 5 ms dx do not, so the verdict line says "none"; under ``--drive-scheme
mujoco`` the sub-micrometre excursions are first order in the step (10-30 %).
``--integrator``, ``--overrides`` and ``--off`` give the page's ablations; ``--drive-scheme`` is the
environment's default (``"midpoint"``) unless given: ``mujoco`` runs MuJoCo's own stepping of the
drive (docs/model.md, "Drive scheme").

Usage: ``python benchmarks/convergence.py [--steps-us 200 100 50 25] [--duration S]
[--controllers pid,feedforward,residual-sac-setpoint] [--integrator rk4] [--overrides JSON] [--off cogging]
[--drive-scheme mujoco]``.
Prints one table per controller and condition (and the excursions' values at each step) and, last,
the steps that converge on all three conditions, per controller.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import mujoco

from microg_env.analysis.metrics import MEASURED_METRICS, RunMetrics
from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.params import RigParams, with_overrides
from microg_env.rollout.episode import run_with_metrics
from microg_env.sim.model import DEFAULT_DRIVE_SCHEME, DRIVE_SCHEMES

RELATIVE_TOLERANCE = 0.01
COMPENSATION_TOLERANCE_PP = 0.02


#: MuJoCo's integrators by the name ``--integrator`` takes (the model's own: implicitfast, euler
#: for the midpoint drive).
INTEGRATORS = {
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
#: The metrics whose values (not only deviations) are printed, in um.
SHOWN_UM = ("flexible_unit_excursion_free_fall_m", "flexible_unit_excursion_collision_m")


def run(controller: str, condition: int, physics_step_s: float, options: argparse.Namespace) -> RunMetrics:
    """One 30 s condition (or ``--duration``) on the rig of ``options`` (its overrides, the
    imperfections it switches off, the integrator, the drive scheme); a model-based controller
    knows the overrides."""
    params = with_overrides(RigParams(), options.overrides)
    imperfections = dict.fromkeys(options.off, False)
    env = MicroGravityLandingEnv(
        condition=condition,
        physics_step_s=physics_step_s,
        params=params,
        imperfections=imperfections,
        drive_scheme=options.drive_scheme,
    )
    if options.integrator is not None:
        env.unwrapped.rig.model.opt.integrator = INTEGRATORS[options.integrator]
    controller = make_controller(controller, env.settings.control_period_s, params)
    return run_with_metrics(env, controller, seed=0, duration_s=options.duration)[2]


def deviations(coarse: RunMetrics, fine: RunMetrics) -> dict[str, float]:
    """Per metric: the coarse value's deviation from the fine one (pp for compensation, else relative)."""
    out = {}
    for name in MEASURED_METRICS:
        a, b = getattr(coarse, name), getattr(fine, name)
        pairs = zip(a, b, strict=True) if isinstance(a, list) else [(a, b)]
        worst = 0.0
        for x, y in pairs:
            if not (math.isfinite(x) and math.isfinite(y)):
                continue
            worst = max(worst, abs(x - y) if name == "compensation_error_pct" else abs(x / y - 1.0))
        out[name] = worst
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps-us", type=float, nargs="+", default=[200.0, 100.0, 50.0, 25.0])
    parser.add_argument("--duration", type=float, default=None, help="simulated time per run (default: 30 s)")
    parser.add_argument("--controllers", default="pid,feedforward,residual-sac-setpoint")
    parser.add_argument("--integrator", choices=tuple(INTEGRATORS), default=None, help="default: the scheme's")
    parser.add_argument("--drive-scheme", choices=DRIVE_SCHEMES, default=DEFAULT_DRIVE_SCHEME)
    parser.add_argument(
        "--overrides", type=json.loads, default={}, help="rig parameters, e.g. '{\"servo.cogging_torque_n_m\": 0}'"
    )
    parser.add_argument(
        "--off", type=lambda text: text.split(","), default=[], help="imperfections switched off, e.g. cogging"
    )
    args = parser.parse_args(argv)
    steps = sorted(s * 1e-6 for s in args.steps_us)
    verdicts = []
    for controller in args.controllers.split(","):
        converged = {step: True for step in steps}
        for condition in (1, 2, 3):
            results = {step: run(controller, condition, step, args) for step in steps}
            print(f"{controller}, condition {condition}: deviation from the run at a 4x finer step", end=" ")
            print("(compensation error in pp)")
            print(f"  {'metric':<40}" + "".join(f"{step * 1e6:>10.1f}us" for step in steps))
            table = {step: deviations(results[step], results[step / 4]) for step in steps if step / 4 in results}
            for name in MEASURED_METRICS:
                cells = "".join(f"{table[s][name]:>12.4g}" if s in table else f"{'-':>12}" for s in steps)
                print(f"  {name:<40}{cells}")
            for name in SHOWN_UM:
                cells = "".join(f"{getattr(results[s], name) * 1e6:>12.4f}" for s in steps)
                print(f"  {name + ' (um)':<40}{cells}")
            for step, deviation in table.items():
                ok = all(
                    value <= (COMPENSATION_TOLERANCE_PP if name == "compensation_error_pct" else RELATIVE_TOLERANCE)
                    for name, value in deviation.items()
                )
                converged[step] = converged[step] and ok
            for step in steps:
                if step not in table:
                    converged[step] = False
        good = [step for step, ok in converged.items() if ok]
        verdicts.append(f"{controller}: " + (", ".join(f"{s * 1e6:g} us" for s in good) or "none"))
    print("converged on all three conditions:", "; ".join(verdicts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
