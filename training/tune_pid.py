"""Tune the PID baselines by simulation; the result goes into microg_env/config/controllers.toml.

Method (docs/controllers.md, "Controllers"):

1. Structure: v = Kp x + Ki integral(x) + D on the grating ruler's x, commanding the drive's speed.
2. Steady state: in a free fall at constant acceleration the loop holds x at F / (k + M Ki), so the
   compensation error is 1 / (1 + Ki / w0^2), w0^2 = k / M (k: the flexible unit's stiffness on x,
   Eq. 17's -35.51 N/mm read literally, so w0^2 = -57.3 s^-2 and the descent is fast by
   |w0^2| / (Ki - |w0^2|)). Ki sets it: 5800 s^-2 for 1 %, 29000 s^-2 for 0.2 %.
3. Dynamics: with an ideal drive the x loop is (1 + Kd) s^2 + Kp s + (Ki + w0^2) for the derivative
   of the error; the derivative on the support's measured speed instead divides Kp and Ki by
   1 + Kd. Kp is set for a damping ratio zeta of that pair (Ki scaled by 1 + Kd for pid-dom, so
   both variants have the same steady state).
4. Robustness: the drive's 100 Hz speed loop, its 1 ms torque filter, one control period of
   command delay and the zero-order hold cost phase, so the chosen candidate must also stay stable
   with every gain doubled (gain margin >= 2), on every condition, with every imperfection on
   (the QZS guide's LuGre friction included).
5. Choice: candidates are ranked by the cost J = mean |compensation error| [%] over the load
   stages of conditions 1-3 + (flexible-unit excursion at collision [um]) / 10, seed 0; the first
   robust one in that order wins.

Run: ``python training/tune_pid.py`` (each gain set on conditions 1-3, with its doubled gains, as
rigs of one batch per condition: microg_env/experiments/tuning.py). It prints every candidate and
the best gains of ``pid`` and ``pid-dom``.
"""

from __future__ import annotations

import itertools
import sys

from microg_env.experiments.tuning import best, candidate_gains, omega0_squared, score
from microg_env.params import PHYSICS_STEP_S
from microg_env.rollout.spec import RunSpec

KI_GRID = (10_000.0, 12_500.0, 15_000.0, 17_500.0, 20_000.0)
ZETA_GRID = (0.5, 0.7, 1.0)
KD_GRID = {"pid": (0.0, 1.0), "pid-dom": (0.05, 0.2)}


def main() -> int:
    w0 = omega0_squared(RunSpec())
    print(f"physics step {PHYSICS_STEP_S:g} s; w0^2 = k / M = {w0:.2f} s^-2", flush=True)
    for name, kd_grid in KD_GRID.items():
        schedules = [RunSpec(f"condition-{n}", name) for n in (1, 2, 3)]
        dom = name == "pid-dom"
        grid = list(itertools.product(KI_GRID, ZETA_GRID, kd_grid))
        candidates = [candidate_gains(ki, zeta, kd, dom, w0) for ki, zeta, kd in grid]
        scored = score(candidates, schedules, workers=2)
        for (_, zeta, kd), c in zip(grid, scored, strict=True):
            print(
                f"{name:8s} Kp {c.gains.kp_per_s:7.1f} Ki {c.gains.ki_per_s2:8.0f} Kd {kd:4.2f} zeta {zeta:3.1f}: "
                f"J {c.cost:7.3f}  |err| {c.error_pct:6.3f} %  collision x {c.collision_um:6.2f} um  robust {c.robust}",
                flush=True,
            )
        chosen = best(scored)
        print(f"best {name}: {chosen.gains} (J = {chosen.cost:.3f})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
