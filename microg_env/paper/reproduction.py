"""The runs behind the reproduction report: every simulation :mod:`microg_env.paper.report` shows.

* the paper's three conditions (Table 2) with the tuned PID, every imperfection on, once with
  Table 1's pad and once with the pad calibrated to the experiments (stored fits,
  config/pads.toml);
* Eq. (17)'s two readings (the literal negative residual stiffness and a restoring one), each
  with the tuned PID and with an integral gain of 4000 s^-2, through each condition's free fall;
* the 50 g stage of condition 3 on several seeds with the balancer between frame and support and
  in parallel with the QZS, to show what the balancer's thermal drift does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from microg_env.paper.calibration import Calibration, stored_calibration, with_pad
from microg_env.params import RigParams
from microg_env.rollout.runner import RunResult, run_each
from microg_env.rollout.spec import RunSpec
from microg_env.scenarios import CONDITIONS

PADS = ("paper", "calibrated")
NUMBERS = (1, 2, 3)
#: Eq. (17)'s readings: the sign of the residual stiffness k in F = F0 - k x.
READINGS = {"literal": -1.0, "restoring": 1.0}
#: The integral gain (s^-2) with which the literal reading falls as fast as the paper's simulation,
#: and the proportional gain that gives its x loop a damping ratio of 0.7.
PAPER_LIKE_GAINS = (88.0, 4000.0)
PLACEMENTS = ("frame_support", "support_lander")
DRIFT_SEEDS = (0, 1, 2)
#: Condition 3's 50 g stage: the foot reaches 25 mm after ~8.7 s.
FIFTY_GRAM_STAGE_S = 8.5


@dataclass(frozen=True)
class Reproduction:
    """Everything the report shows."""

    runs: dict[tuple[str, int], RunResult]  # one condition with one pad: the run, its reference, its metrics
    calibration: Calibration  # the pad fitted to the paper's experiments
    simulation_fit: Calibration  # the pad with which this model lands as the paper's simulation did
    pads: dict[str, tuple[float, float]]  # K, D of each pad
    #: Compensation errors (%) of each stage by (reading, controller, condition); controller "pid"
    #: or "ki4000".
    eq17: dict[tuple[str, str, int], list[float]]
    #: The 50 g stage's compensation error (%) on each of DRIFT_SEEDS, by balancer placement.
    drift: dict[str, list[float]]
    duration_s: float
    seed: int
    controller: str


def _free_fall_s(number: int) -> float:
    """Simulated time that covers condition ``number``'s free fall and its touchdown."""
    params = RigParams()
    return CONDITIONS[number].ideal_touchdown_s(params.lander.mass_kg, params.gravity_m_s2) + 0.2


def total_steps(duration_s: float) -> int:
    """Control steps :func:`compute` runs at 1 kHz (for a progress bar)."""
    main = len(PADS) * len(NUMBERS) * round(duration_s * 1e3)
    free_falls = [round(min(_free_fall_s(n), duration_s) * 1e3) for n in NUMBERS]
    reused = [round(_free_fall_s(n) * 1e3) if duration_s >= _free_fall_s(n) else 0 for n in NUMBERS]
    eq17 = len(READINGS) * 2 * sum(free_falls) - sum(reused)  # the tuned literal runs reuse the main ones
    drift = len(PLACEMENTS) * len(DRIFT_SEEDS) * round(min(FIFTY_GRAM_STAGE_S, duration_s) * 1e3)
    return main + eq17 + drift


def compute(
    duration_s: float = 30.0, seed: int = 0, progress: Callable[[int], None] | None = None, workers: int | None = None
) -> Reproduction:
    """Run everything the report shows (``progress(steps)`` as each run ends), the runs in parallel on
    ``workers`` processes (default: every usable core; 1: in this process, one after another)."""
    mains, eq17_specs, drift_specs = {}, {}, {}
    pads = {}
    for pad in PADS:
        params = with_pad(RigParams(), pad)
        pads[pad] = (params.pad.stiffness_n_per_m, params.pad.damping_n_s_per_m)
        overrides = {"pad.stiffness_n_per_m": pads[pad][0], "pad.damping_n_s_per_m": pads[pad][1]}
        for number in NUMBERS:
            mains[pad, number] = RunSpec(f"condition-{number}", "pid", seed, overrides=overrides, duration_s=duration_s)
    paper_like = {"kp_per_s": PAPER_LIKE_GAINS[0], "ki_per_s2": PAPER_LIKE_GAINS[1]}
    for reading, sign in READINGS.items():
        overrides = {"qzs.residual_stiffness_n_per_m": sign * 35510.0}
        for label, gains in (("pid", {}), ("ki4000", paper_like)):
            for number in NUMBERS:
                if (reading, label) == ("literal", "pid") and duration_s >= _free_fall_s(number):
                    continue  # the main run on Table 1's pad is this run and longer
                length = min(_free_fall_s(number), duration_s)
                eq17_specs[reading, label, number] = RunSpec(
                    f"condition-{number}", "pid", seed, overrides, gains, duration_s=length
                )
    for placement in PLACEMENTS:
        for drift_seed in DRIFT_SEEDS:
            length = min(FIFTY_GRAM_STAGE_S, duration_s)
            drift_specs[placement, drift_seed] = RunSpec(
                "condition-3", "pid", drift_seed, {"balancer.placement": placement}, duration_s=length
            )
    specs = [*mains.values(), *eq17_specs.values(), *drift_specs.values()]
    results = run_each(specs, workers, progress)
    runs = dict(zip(mains, results, strict=False))
    metrics = {spec: result.metrics for spec, result in zip(specs, results, strict=True)}
    eq17 = {key: metrics[spec].compensation_error_pct for key, spec in eq17_specs.items()}
    for number in NUMBERS:
        eq17.setdefault(("literal", "pid", number), runs["paper", number].metrics.compensation_error_pct)
    eq17 = {(r, label, n): eq17[r, label, n] for r in READINGS for label in ("pid", "ki4000") for n in NUMBERS}
    drift = {
        placement: [metrics[drift_specs[placement, s]].compensation_error_pct[0] for s in DRIFT_SEEDS]
        for placement in PLACEMENTS
    }
    return Reproduction(
        runs,
        stored_calibration("calibrated"),
        stored_calibration("paper-simulation"),
        pads,
        eq17,
        drift,
        duration_s,
        seed,
        "pid",
    )
