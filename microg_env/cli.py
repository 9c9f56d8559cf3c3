"""The ``microg`` command.

Every user error (a bad option or value) prints one line to stderr and exits with code 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from microg_env.analysis.metrics import RunMetrics
from microg_env.controllers import CONTROLLER_NAMES
from microg_env.imperfections import Imperfections
from microg_env.paper.calibration import pad_values
from microg_env.params import RigParams
from microg_env.scenarios import LoadStep, Scenario, condition
from microg_env.sim.drop import DropReport, drop_test


class UsageError(Exception):
    """A bad command line; reported on one line with exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # argparse would print the whole usage first
        raise UsageError(f"{self.prog}: error: {message}")


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def _print_drop(report: DropReport) -> None:
    c = report.contact
    print(
        f"Pad drop test: M = {report.mass_kg:g} kg, K = {report.stiffness_n_per_m:g} N/m, "
        f"D = {report.damping_n_s_per_m:g} N s/m, V0 = {report.impact_speed_m_s * 1e3:g} mm/s "
        f"(xi = {c.xi:.4f}, w_d = {c.omega_d:.4f} rad/s)"
    )
    rows = (
        ("contact time [s]", report.contact_time_s, 1.0, "Eq. 7"),
        ("restitution [-]", report.restitution, 1.0, "Eq. 9"),
        ("peak deformation [mm]", report.max_deformation_m, 1e3, "Eq. 4"),
        ("fitted stiffness K [N/m]", report.fitted_stiffness_n_per_m, 1.0, "set"),
        ("fitted damping D [N s/m]", report.fitted_damping_n_s_per_m, 1.0, "set"),
    )
    print(f"{'quantity':<26}{'MuJoCo':>12}{'closed form':>14}{'rel. error':>12}  source")
    for label, value, scale, source in rows:
        print(
            f"{label:<26}{value.sim * scale:>12.5g}{value.analytic * scale:>14.5g}{value.rel_error:>+12.3%}  {source}"
        )
    print(
        f"The paper's approximations, which ignore that the pad cannot pull: t* = pi/w_d = "
        f"{c.half_period_s:.4f} s (Eq. 10), c_r = {c.restitution_half_period:.4f} (Eq. 12)."
    )


def _cmd_drop(args: argparse.Namespace) -> int:
    stiffness, damping = pad_values(args.pad)
    stiffness = stiffness if args.stiffness is None else args.stiffness
    damping = damping if args.damping is None else args.damping
    report = drop_test(args.mass, stiffness, damping, args.velocity)
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        _print_drop(report)
    return 0


def write_atomically(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename: never a half-written file."""
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise UsageError(f"microg: error: cannot write {path}: folder {directory} does not exist")
    try:
        handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=directory)
    except OSError as error:
        raise UsageError(f"microg: error: cannot write {path}: {error.strerror}") from None
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as stream:
            stream.write(text)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _cmd_export_mjcf(args: argparse.Namespace) -> int:
    from microg_env.sim.model import build_spec

    stiffness, damping = pad_values(args.pad)
    params = RigParams()
    params = replace(params, pad=replace(params.pad, stiffness_n_per_m=stiffness, damping_n_s_per_m=damping))
    spec, _ = build_spec(params, tuple(args.load))
    spec.compile()
    write_atomically(Path(args.output), spec.to_xml())
    print(f"wrote {args.output}")
    return 0


def _load_step(text: str) -> LoadStep:
    """KG[@HEIGHT_MM]: a weight placed at t = 0, or when the foot is HEIGHT_MM above the pad."""
    mass, _, height = text.partition("@")
    try:
        return LoadStep(float(mass), float(height) * 1e-3 if height else None)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"bad load {text!r}: {error}") from None


def _scenario(args: argparse.Namespace) -> Scenario:
    stiffness, damping = pad_values(args.pad)
    scenario = replace(condition(args.condition), pad_stiffness_n_per_m=stiffness, pad_damping_n_s_per_m=damping)
    if args.load:
        scenario = replace(scenario, name="custom", loads=tuple(args.load))
    if args.height is not None:
        scenario = replace(scenario, name="custom", descent_height_m=args.height * 1e-3)
    if args.duration is not None:
        scenario = replace(scenario, duration_s=args.duration)
    return scenario


def _format_row(label: str, values: list[float], scale: float, spec: str) -> str:
    cells = "".join(f"{'-' if v is None or v != v else format(v * scale, spec):>12}" for v in values)
    return f"  {label:<36}{cells}"


def _print_run(scenario: Scenario, args: argparse.Namespace, m: RunMetrics) -> None:
    loads = ", ".join(
        f"{load.mass_kg:g} kg" + ("" if load.height_m is None else f" at {load.height_m * 1e3:g} mm")
        for load in scenario.loads
    )
    print(
        f"{scenario.name}: loads {loads}; descent from {scenario.descent_height_m * 1e3:g} mm; "
        f"{args.pad} pad (K = {scenario.pad_stiffness_n_per_m:.1f} N/m, "
        f"D = {scenario.pad_damping_n_s_per_m:.1f} N s/m); "
        f"controller {args.controller}; seed {args.seed}; {scenario.duration_s:g} s at "
        f"{args.control_period:g} us; imperfections {'off' if args.ideal else 'on'}"
    )
    if m.termination_reason:
        print(f"  episode ended early: {m.termination_reason}")
    stages = len(m.descent_accel_m_s2)
    print(f"{'free fall, per load stage':<38}" + "".join(f"{'stage ' + str(i + 1):>12}" for i in range(stages)))
    print(_format_row("external load [kg]", list(scenario.stages_kg), 1.0, ".3g"))
    print(_format_row("descent acceleration [mm/s^2]", m.descent_accel_m_s2, 1e3, ".4f"))
    print(_format_row("ideal m g/(M+m) [mm/s^2]", m.ideal_descent_accel_m_s2, 1e3, ".4f"))
    print(_format_row("compensation error [%]", m.compensation_error_pct, 1.0, "+.3f"))
    print(_format_row("residual gravity error [g]", m.residual_gravity_g, 1.0, "+.2e"))
    print(_format_row("microgravity level [g]", m.microgravity_level_g, 1.0, ".2e"))
    print("flexible unit")
    print(_format_row("max |x| in free fall [um]", [m.flexible_unit_excursion_free_fall_m], 1e6, ".3f"))
    print(_format_row("max |x| during the collision [um]", [m.flexible_unit_excursion_collision_m], 1e6, ".3f"))
    print(_format_row("support force variation [N]", [m.support_force_variation_n], 1.0, ".4f"))
    print(f"{'first landing':<38}{'rig':>12}{'ideal':>12}")
    print(_format_row("peak pad deformation [mm]", [m.max_deformation_m, m.reference_max_deformation_m], 1e3, ".3f"))
    print(
        _format_row(
            "collision acceleration [mm/s^2]", [m.collision_accel_m_s2, m.reference_collision_accel_m_s2], 1e3, ".2f"
        )
    )
    print(_format_row("contact time [s]", [m.contact_time_s, m.reference_contact_time_s], 1.0, ".4f"))
    print(_format_row("restitution [-]", [m.restitution, m.reference_restitution], 1.0, ".4f"))
    print(_format_row("rebound height [mm]", [m.rebound_height_m], 1e3, ".2f"))
    print(_format_row("RMS height error to rebound end [mm]", [m.reference_rms_height_error_m], 1e3, ".4f"))


def _cmd_run(args: argparse.Namespace) -> int:
    from microg_env.analysis.evaluate import run_with_metrics
    from microg_env.controllers import make_controller
    from microg_env.envs.landing import MicroGravityLandingEnv

    if args.plot is not None:
        _check_writable(Path(args.plot))
    scenario = _scenario(args)
    period = args.control_period * 1e-6
    imperfections = Imperfections.none() if args.ideal else Imperfections()
    env = MicroGravityLandingEnv(scenario=scenario, control_period_s=period, imperfections=imperfections)
    controller = make_controller(args.controller, period)
    trajectory, reference, metrics = run_with_metrics(env, controller, seed=args.seed)
    if args.json:
        print(json.dumps(metrics.as_dict(), indent=2))
    else:
        _print_run(scenario, args, metrics)
    if args.plot is not None:
        from microg_env.analysis.plots import plot_run

        plot_run(trajectory, reference, f"{scenario.name}, {args.controller}, seed {args.seed}", Path(args.plot))
        if not args.json:
            print(f"wrote {args.plot}")
    return 0


def _check_writable(path: Path) -> None:
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir() or not os.access(directory, os.W_OK):
        raise UsageError(f"microg: error: cannot write {path}: folder {directory} is missing or not writable")


def _add_pad_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--pad",
        choices=("paper", "calibrated"),
        default="paper",
        help="the pad: Table 1's K and D (paper) or K and D fitted to the experiments (calibrated)",
    )


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from microg_env.paper.calibration import calibrate
    from microg_env.paper.report import paper_residuals
    from microg_env.paper.tables import CONDITIONS as PAPER

    result = calibrate()
    if args.json:
        print(json.dumps(result.as_dict(), indent=2))
        return 0
    print(
        f"Pad calibrated to the paper's experiments (Tables 5-6, actual) by least squares: "
        f"K = {result.stiffness_n_per_m:.1f} N/m, D = {result.damping_n_s_per_m:.1f} N s/m "
        f"({result.iterations} iterations; Table 1: 4666 N/m, 200 N s/m)"
    )
    paper_deformation, paper_acceleration = paper_residuals()
    print(f"{'residual, model - experiment, % of experiment':<48}{'cond. 1':>10}{'cond. 2':>10}{'cond. 3':>10}")
    rows = (
        ("peak deformation, calibrated", result.max_deformation_pct),
        ("peak deformation, the paper's simulation", paper_deformation),
        ("collision acceleration, calibrated", result.collision_accel_pct),
        ("collision acceleration, the paper's simulation", paper_acceleration),
    )
    for label, values in rows:
        print(f"  {label:<46}" + "".join(f"{v:>+10.2f}" for v in values))
    measured = ", ".join(
        f"{c.measured_max_deformation_mm:g} mm / {c.measured_collision_accel_mm_s2:g} mm/s^2" for c in PAPER.values()
    )
    print(f"experiments (deformation / acceleration): {measured}; RMS residual {result.rms_residual_pct:.2f} %")
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from microg_env.paper import report

    if args.duration is not None and not 0 < args.duration <= 600:
        raise ValueError(f"duration must be in (0, 600] s, got {args.duration!r}")
    out = Path(args.out)
    report.check_output(out)
    duration = 30.0 if args.duration is None else args.duration
    try:
        from tqdm import tqdm
    except ImportError:
        raise ValueError("microg reproduce needs the report extra: pip install 'microg-env[report]'") from None
    report.figure_class()  # fail now, not after the runs, if matplotlib is missing
    with tqdm(
        total=report.total_steps(duration),
        unit="step",
        unit_scale=True,
        desc="reproduce",
        file=sys.stderr,
        disable=args.quiet,
    ) as bar:
        reproduction = report.compute(duration_s=duration, seed=args.seed, progress=bar.update)
    report.write(reproduction, out)
    print(f"wrote {out / 'report.md'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="microg", description="MuJoCo model of the QZS microgravity landing rig (Jia et al. 2024).")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    drop = commands.add_parser(
        "drop",
        help="drop a lander on the pad and compare with the Section 2 closed form",
        description="Drop a lander on the rubber pad in MuJoCo (no field, rig removed) and compare contact time, "
        "restitution, peak deformation and the fitted K, D with the Section 2 spring-damper.",
    )
    defaults = RigParams()
    drop.add_argument("--mass", type=_float, default=defaults.lander.mass_kg, metavar="KG", help="lander mass")
    drop.add_argument("--stiffness", type=_float, metavar="N_PER_M", help="pad stiffness K (default: --pad's)")
    drop.add_argument("--damping", type=_float, metavar="N_S_PER_M", help="pad damping D (default: --pad's)")
    _add_pad_option(drop)
    drop.add_argument("--velocity", type=_float, default=0.0373, metavar="M_PER_S", help="impact speed")
    drop.add_argument("--json", action="store_true", help="print one JSON object")
    drop.set_defaults(handler=_cmd_drop)

    run = commands.add_parser(
        "run",
        help="run a test condition with a baseline controller and print its metrics",
        description="Run one of the paper's test conditions (or a custom load schedule) in the environment with a "
        "baseline controller, and print the microgravity and landing metrics beside the ideal-microgravity reference.",
    )
    run.add_argument("--condition", type=int, choices=(1, 2, 3), default=1, help="the paper's condition (Table 2)")
    run.add_argument(
        "--load",
        type=_load_step,
        action="append",
        default=[],
        metavar="KG[@HEIGHT_MM]",
        help="a test weight placed at t = 0, or once the foot is HEIGHT_MM above the pad; repeat for more "
        "(replaces the condition's loads)",
    )
    run.add_argument("--height", type=_float, metavar="MM", help="descent height of the foot above the pad")
    run.add_argument("--controller", choices=CONTROLLER_NAMES, default="pid", help="baseline controller")
    run.add_argument("--duration", type=_float, metavar="S", help="simulated time (default 30 s)")
    run.add_argument("--seed", type=int, default=0, help="seed of sensor noise and drift")
    run.add_argument(
        "--control-period", type=_float, default=1000.0, metavar="US", help="control period (paper: 1000/500/200/100)"
    )
    run.add_argument("--ideal", action="store_true", help="switch every imperfection off")
    _add_pad_option(run)
    run.add_argument("--json", action="store_true", help="print one JSON object of metrics")
    run.add_argument("--plot", metavar="FILE", help="write height, x, acceleration and pad force over time (PNG)")
    run.set_defaults(handler=_cmd_run)

    reproduce = commands.add_parser(
        "reproduce",
        help="reproduce the paper's figures and tables beside this model's (the main job)",
        description="Run conditions 1-3 with the PID baseline, with Table 1's pad and with the calibrated pad, and "
        "write a Markdown report with the equivalents of the paper's Figures 3-7 and Tables 3-6.",
    )
    reproduce.add_argument("--out", default="results/reproduction", metavar="DIR", help="report folder (replaced)")
    reproduce.add_argument("--duration", type=_float, metavar="S", help="simulated time per condition (default 30)")
    reproduce.add_argument("--seed", type=int, default=0, help="seed of sensor noise and drift")
    reproduce.add_argument("--quiet", action="store_true", help="no progress bar")
    reproduce.set_defaults(handler=_cmd_reproduce)

    calibrate = commands.add_parser(
        "calibrate",
        help="fit the pad's K and D to the paper's experiments",
        description="Fit the pad's effective stiffness and damping by least squares to the experimental peak "
        "deformations and collision accelerations of Tables 5-6, and print the fit and its residuals.",
    )
    calibrate.add_argument("--json", action="store_true", help="print one JSON object")
    calibrate.set_defaults(handler=_cmd_calibrate)

    export = commands.add_parser(
        "export-mjcf",
        help="write the resolved rig model (every derived value filled in) as one MJCF file",
        description="Write the rig built from the default parameters as a self-contained MJCF file.",
    )
    export.add_argument("output", metavar="FILE", help="MJCF file to write")
    export.add_argument("--load", type=_float, action="append", default=[], metavar="KG", help="add a test weight")
    _add_pad_option(export)
    export.set_defaults(handler=_cmd_export_mjcf)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``microg`` console script."""
    try:
        args = build_parser().parse_args(argv)
        return args.handler(args)
    except UsageError as error:
        print(error, file=sys.stderr)
        return 2
    except ValueError as error:
        print(f"microg: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
