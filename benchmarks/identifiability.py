"""Identifiability of the rig's unknowns from its logs: what ``microg identify`` recovers.

Each draw hides a rig: the parameters ``identify`` fits (:data:`FIT_SCALES`), drawn uniformly from
:data:`HIDDEN` (the drive's speed loop over the 70-150 Hz the sensitivity study calls plausible,
...). The paper's PID lands a 1 kg weight from 30 mm on it (seed = the draw), every imperfection
on, the sensors noisy and quantised, and the run is logged as a rig logs it (``microg run --log``).
``identify`` then fits every parameter from the paper's rig, told nothing of the draw, on two
excitations cut from the same log: the free fall alone (the first 1.8 s, before the touchdown at
about 1.95 s) and the free fall with the landing (3.5 s). The replay draws its own sensor noise and
balancer drift (seed 0), as a real rig's differ from any model's.

Usage: ``python benchmarks/identifiability.py [--draws 5] [--workers 2] [--seconds 1.8 3.5]
[--max-iterations 50]``. Prints, per draw and
excitation, each parameter's hidden value, its fit and 95 % interval, and the error in intervals;
then, per excitation and parameter, the largest relative error and how many intervals held the
hidden value: the table docs/model.md ("Identification") shows.
"""

from __future__ import annotations

import argparse
import functools
import multiprocessing
import time

import numpy as np

#: The hidden rigs' ranges: (low, high) of each fitted parameter.
HIDDEN = {
    "servo.speed_loop_gain_hz": (70.0, 150.0),
    "servo.torque_filter_s": (0.5e-3, 2.0e-3),
    "servo.cogging_torque_n_m": (0.1, 0.5),
    "qzs.residual_stiffness_n_per_m": (-45000.0, -25000.0),
    "sensors.ruler_zero_offset_m": (-5e-6, 5e-6),
    "pad.stiffness_n_per_m": (3500.0, 6000.0),
    "pad.damping_n_s_per_m": (150.0, 250.0),
}
#: The excitations, by the log's first seconds each keeps (by default: before and after the touchdown).
EXCITATIONS = ("free fall", "free fall and landing")
SECONDS = (1.8, 3.5)


def hidden_rig(draw: int) -> dict[str, float]:
    rng = np.random.default_rng(1000 + draw)
    return {name: float(rng.uniform(*bounds)) for name, bounds in HIDDEN.items()}


def one_draw(draw: int, seconds: tuple[float, ...] = SECONDS, max_iterations: int = 50) -> list[dict]:
    from microg_env.experiments.identify import identify
    from microg_env.logs import RigLog
    from microg_env.rollout.replay import LogRecorder
    from microg_env.rollout.runner import run
    from microg_env.rollout.spec import RunSpec

    hidden = hidden_rig(draw)
    recorder = LogRecorder()
    spec = RunSpec("condition-1", "pid", seed=draw, overrides=hidden, loads=((1.0, None),), descent_height_m=0.03,
                   duration_s=max(seconds))  # fmt: skip
    run(spec, on_step=recorder)
    full = recorder.log()
    rows = []
    for excitation, length in zip(EXCITATIONS, seconds, strict=True):
        n = round(length / full.control_period_s)
        log = RigLog({k: v[:n] for k, v in full.columns.items()}, full.descent_height_m, full.loads, excitation)
        start = time.perf_counter()
        result = identify([log], max_iterations=max_iterations)
        wall = time.perf_counter() - start
        for name, value in result.values.items():
            truth = hidden[name]
            rows.append(
                {
                    "draw": draw,
                    "excitation": excitation,
                    "parameter": name,
                    "hidden": truth,
                    "fit": value,
                    "half_width": result.half_widths[name],
                    "relative_error": abs(value - truth) / abs(truth),
                    "in_interval": abs(value - truth) <= result.half_widths[name],
                    "wall_s": wall,
                    "rms_nm": {k: v * 1e9 for k, v in result.rms.items()},
                }
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seconds", type=float, nargs=2, default=SECONDS, help="each excitation's length, s")
    parser.add_argument("--max-iterations", type=int, default=50)
    args = parser.parse_args(argv)
    job = functools.partial(one_draw, seconds=tuple(args.seconds), max_iterations=args.max_iterations)
    if args.workers > 1:
        with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
            batches = pool.map(job, range(args.draws))
    else:
        batches = [job(draw) for draw in range(args.draws)]
    rows = [row for rows in batches for row in rows]
    for row in rows:
        print(
            f"draw {row['draw']} {row['excitation']:<22} {row['parameter']:<32} hidden {row['hidden']:<12.5g} "
            f"fit {row['fit']:<12.5g} +- {row['half_width']:<10.3g} error {row['relative_error']:.2%}"
            f"{'' if row['in_interval'] else '  (outside)'}"
        )
    print("\n| parameter | " + " | ".join(f"{e}: worst error, intervals holding it" for e in EXCITATIONS) + " |")
    print("|---|" + "---|" * len(EXCITATIONS))
    for name in HIDDEN:
        cells = []
        for excitation in EXCITATIONS:
            mine = [r for r in rows if r["parameter"] == name and r["excitation"] == excitation]
            if not mine:
                cells.append("not fitted")
                continue
            worst = max(r["relative_error"] for r in mine)
            held = sum(r["in_interval"] for r in mine)
            cells.append(f"{worst:.2%}, {held}/{len(mine)}")
        print(f"| `{name}` | " + " | ".join(cells) + " |")
    walls = {e: np.median([r["wall_s"] for r in rows if r["excitation"] == e]) for e in EXCITATIONS}
    print("\nmedian wall time per fit: " + ", ".join(f"{e} {w:.0f} s" for e, w in walls.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
