"""The ``microg`` commands on the rig and the paper: ``drop``, ``run``, ``view``, ``reproduce``,
``calibrate`` and ``export-mjcf``."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import math
import threading
from pathlib import Path

from microg_env.cli.common import (
    DROP_OPTIONS,
    add_duration_option,
    add_pad_options,
    add_physics_step_option,
    add_rig_option,
    controller_name,
    count,
    naming,
    number,
    pad_from_options,
    progress_bar,
    rig_overrides,
    run_options,
    seed_number,
)
from microg_env.imperfections import IMPERFECTION_NAMES
from microg_env.interface import CONTROLLER_NAMES
from microg_env.params import CONTROL_PERIOD_RANGE_S, CONTROL_PERIOD_S, LOAD_CAPACITY_KG
from microg_env.scenarios import MIN_HEIGHT_M, MIN_LOAD_KG, LoadStep
from microg_env.workers import usable_cores

#: Figure formats ``--plot`` writes.
PLOT_SUFFIXES = (".png", ".pdf", ".svg")

#: Where ``microg reproduce`` writes by default; its missing parents are created.
DEFAULT_REPORT_DIR = "results/reproduction"


def _load_step(text: str) -> LoadStep:
    """KG[@HEIGHT_MM]: a weight placed at t = 0, or when the foot is HEIGHT_MM above the pad."""
    mass, at, height = text.partition("@")
    if at and not height.strip():
        raise argparse.ArgumentTypeError(f"bad load {text!r}: no height after '@'")
    try:
        return LoadStep(float(mass), float(height) * 1e-3 if height else None)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"bad load {text!r}: {error}") from None


def _print_drop(report) -> None:
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
    from microg_env.sim.drop import drop_test

    pad = pad_from_options(args)
    try:
        report = drop_test(args.mass, pad.stiffness_n_per_m, pad.damping_n_s_per_m, args.velocity)
    except ValueError as error:
        raise naming(error, DROP_OPTIONS, every=True) from None
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        _print_drop(report)
    return 0


def _cmd_export_mjcf(args: argparse.Namespace) -> int:
    from microg_env.files import check_output_file, write_text
    from microg_env.params import RigParams, with_overrides
    from microg_env.sim.limits import check_pad_model
    from microg_env.sim.model import export_spec

    output = check_output_file(args.output, "FILE", (".xml",))
    params = with_overrides(RigParams(), rig_overrides(args))
    step = args.physics_step / 1e6  # 10 * 1e-6 is 9.999999999999999e-06, below the 10 us floor
    try:
        check_pad_model(params.pad, params.lander.mass_kg + sum(args.load), step, "export-mjcf")
    except ValueError as error:
        raise naming(error, run_options(args)) from None
    spec = export_spec(params, tuple(args.load), physics_step_s=step)
    write_text(output, spec.to_xml())
    print(f"wrote {output}")
    return 0


def _run_spec(args: argparse.Namespace):
    """The run ``microg run``'s options describe."""
    from microg_env.rollout.spec import RunSpec

    if args.randomize and args.no_imperfections:
        raise ValueError("--randomize: a rig with --no-imperfections has nothing to randomise; give one of them")
    overrides = rig_overrides(args)
    return RunSpec(
        scenario=f"condition-{args.condition}",
        controller=args.controller,
        seed=args.seed,
        overrides=overrides,
        imperfections=dict.fromkeys(IMPERFECTION_NAMES, False) if args.no_imperfections else {},
        randomize=args.randomize,
        control_period_us=args.control_period,
        physics_step_us=args.physics_step,
        duration_s=args.duration,
        loads=tuple((load.mass_kg, load.height_m) for load in args.load) or None,
        descent_height_m=None if args.height is None else args.height * 1e-3,
    )


def _format_row(label: str, values: list[float], scale: float, spec: str) -> str:
    cells = "".join(f"{'-' if v is None or v != v else format(v * scale, spec):>12}" for v in values)
    return f"  {label:<36}{cells}"


def _print_run(scenario, params, args: argparse.Namespace, m) -> None:
    from microg_env.analysis.metrics import INSTANT_WINDOWS_S, in_flight_weights

    pad = params.pad
    rig = "the paper's rig" if args.rig is None else f"rig {args.rig}"
    print(
        f"{scenario.name}: loads {scenario.loads_text}; descent from {scenario.descent_height_m * 1e3:g} mm; "
        f"{rig}, lander {params.lander.mass_kg:g} kg, "
        f"{'' if args.rig is not None else args.pad + ' '}pad (K = {pad.stiffness_n_per_m:.1f} N/m, "
        f"D = {pad.damping_n_s_per_m:.1f} N s/m); "
        f"controller {args.controller}; seed {args.seed}; {scenario.duration_s:g} s at "
        f"{args.control_period:g} us (physics step {args.physics_step:g} us); "
        f"imperfections {'off' if args.no_imperfections else 'on'}"
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
    if m.placement_delay_s:  # under the stage each weight placed in flight begins
        delays = [math.nan] * stages
        for weight, delay in zip(in_flight_weights(scenario), m.placement_delay_s, strict=True):
            delays[weight] = delay
        print(_format_row("weight placed later than ideal [s]", delays, 1.0, "+.3f"))
    print("flexible unit and drive")
    print(_format_row("max |x| in free fall [um]", [m.flexible_unit_excursion_free_fall_m], 1e6, ".3f"))
    print(_format_row("max |x| during the collision [um]", [m.flexible_unit_excursion_collision_m], 1e6, ".3f"))
    for window, change in zip(INSTANT_WINDOWS_S, m.x_change_after_touchdown_m, strict=True):
        print(_format_row(f"x change, {window * 1e3:g} ms from touchdown [um]", [change], 1e6, ".3f"))
    print(_format_row("support force variation [N]", [m.support_force_variation_n], 1.0, ".4f"))
    rated = f"servo RMS torque [N m] (rated {params.servo.rated_torque_n_m:g})"
    print(_format_row(rated, [m.servo_rms_torque_n_m], 1.0, ".3f"))
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
    print(_format_row("RMS height error to rebound apex [mm]", [m.reference_rms_height_error_m], 1e3, ".4f"))
    for name, reason in m.unavailable.items():
        print(f"  not available: {name}: {reason}")


def _cmd_run(args: argparse.Namespace) -> int:
    from microg_env.files import check_output_file
    from microg_env.rollout.runner import run

    plot = None if args.plot is None else check_output_file(args.plot, "--plot", PLOT_SUFFIXES)
    if plot is not None:
        from microg_env.analysis.plots import figure_class

        figure_class()  # fail now, not after the run, if matplotlib is missing
    try:
        spec = _run_spec(args)
    except ValueError as error:
        raise naming(error, run_options(args)) from None
    video, render = None, None
    if args.video is not None:
        from microg_env.analysis.video import VIDEO_SIZE, VIDEO_SUFFIXES, LandingVideo, check_video_support

        path = check_output_file(args.video, "--video", VIDEO_SUFFIXES)
        check_video_support(path)
        title = f"microg: {spec.scenario_schedule().name}, {args.controller}, seed {args.seed}"
        video = LandingVideo(path, title)
        render = {"render_mode": "rgb_array", "width": VIDEO_SIZE[0], "height": VIDEO_SIZE[1]}
    recorder, log = None, None
    if args.log is not None:
        from microg_env.logs import LOG_SUFFIXES, check_parquet_support

        if args.no_imperfections:
            raise ValueError("--log: a rig log is of a rig with every imperfection on, as replay runs it; drop --ideal")
        from microg_env.rollout.replay import LogRecorder

        log = check_output_file(args.log, "--log", LOG_SUFFIXES)
        check_parquet_support(log)
        recorder = LogRecorder()
    watchers = [watcher for watcher in (video, recorder) if watcher is not None]

    def on_step(env, info) -> None:
        for watcher in watchers:
            watcher(env, info)

    steps = round(spec.scenario_schedule().duration_s / spec.control_period_s)
    bars = []  # opened at the first steps run: a run refused while it is built prints only its error

    def progress(done: int) -> None:
        if not bars:
            bars.append(progress_bar("run", args.quiet, steps))
        bars[0].update(done)

    try:
        result = run(spec, on_step=on_step if watchers else None, on_progress=progress, render=render)
    except ValueError as error:
        raise naming(error, run_options(args)) from None
    finally:
        for bar in bars:
            bar.close()
    trajectory, reference, metrics = result.trajectory, result.reference, result.metrics
    if args.json:
        print(json.dumps(metrics.as_dict(), indent=2))
    else:
        _print_run(trajectory.scenario, spec.rig_params(), args, metrics)
    if plot is not None:
        from microg_env.analysis.plots import plot_run

        plot_run(trajectory, reference, f"{trajectory.scenario.name}, {args.controller}, seed {args.seed}", plot)
        if not args.json:
            print(f"wrote {plot}")
    if video is not None:
        video.write()
        if not args.json:
            print(f"wrote {video.path}")
    if recorder is not None:
        from microg_env.logs import write_log

        write_log(recorder.log(), log)
        if not args.json:
            print(f"wrote {log}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from microg_env.analysis.viewer import LiveView, WindowClosed, check_display
    from microg_env.rollout.runner import run

    try:
        spec = _run_spec(args)
    except ValueError as error:
        raise naming(error, run_options(args)) from None
    check_display()
    view = LiveView(f"microg: {spec.scenario_schedule().name}, {args.controller}, seed {args.seed}", args.speed)
    try:
        result = run(spec, on_step=view)
    except WindowClosed:
        print("microg view: the window was closed before the run ended")
        return 0
    except ValueError as error:
        raise naming(error, run_options(args)) from None
    finally:
        view.close()
    _print_run(result.trajectory.scenario, spec.rig_params(), args, result.metrics)
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from microg_env.paper.calibration import calibrate
    from microg_env.paper.findings import paper_residuals
    from microg_env.paper.tables import PUBLISHED

    result = calibrate(source=args.source)
    if args.json:
        print(json.dumps(result.as_dict(), indent=2))
        return 0
    what = "experiments (Tables 5-6, actual)" if args.source == "experiment" else "simulation (Tables 5-6, theoretical)"
    print(
        f"Pad fitted to the paper's {what} by least squares: "
        f"K = {result.stiffness_n_per_m:.1f} N/m, D = {result.damping_n_s_per_m:.1f} N s/m "
        f"({result.iterations} iterations; Table 1: 4666 N/m, 200 N s/m)"
    )
    paper_deformation, paper_acceleration = paper_residuals()
    print(f"{'residual, model - target, % of target':<48}{'cond. 1':>10}{'cond. 2':>10}{'cond. 3':>10}")
    rows = [("peak deformation, fitted", result.max_deformation_pct)]
    rows += [("collision acceleration, fitted", result.collision_accel_pct)]
    if args.source == "experiment":
        rows.insert(1, ("peak deformation, the paper's simulation", paper_deformation))
        rows.append(("collision acceleration, the paper's simulation", paper_acceleration))
        measured = ", ".join(
            f"{c.measured_max_deformation_mm:g} mm / {c.measured_collision_accel_mm_s2:g} mm/s^2"
            for c in PUBLISHED.values()
        )
        print(f"experiments (deformation / acceleration): {measured}")
    for label, values in rows:
        print(f"  {label:<46}" + "".join(f"{v:>+10.2f}" for v in values))
    print(f"RMS residual {result.rms_residual_pct:.2f} %")
    return 0


def _import_quietly(module: str) -> None:
    """Import ``module`` if it imports; if not, the code that uses it reports why, in one line."""
    with contextlib.suppress(Exception):
        importlib.import_module(module)


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from microg_env.analysis.plots import require_matplotlib
    from microg_env.paper import report, reproduction

    if not args.out.strip():
        raise ValueError("--out: the folder name is empty")
    out = Path(args.out)
    if args.out == DEFAULT_REPORT_DIR:
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise ValueError(
                f"--out {args.out!r}: cannot create folder {str(out.parent)!r} ({error.strerror})"
            ) from None
    report.check_output(out)
    require_matplotlib()  # fail now, not after the runs
    # The figures' matplotlib imported (a third of a second) while the runs run, not before them.
    threading.Thread(target=_import_quietly, args=("matplotlib.figure",), daemon=True).start()
    duration = 30.0 if args.duration is None else args.duration
    with progress_bar("reproduce", args.quiet, reproduction.total_steps(duration)) as bar:
        runs = reproduction.compute(duration_s=duration, seed=args.seed, progress=bar.update, workers=args.workers)
    report.write(runs, out, args.workers)
    print(f"wrote {out / 'report.md'}")
    return 0


def _add_episode_options(parser: argparse.ArgumentParser) -> None:
    """The options that say which episode ``run`` and ``view`` show (``_run_spec`` reads them)."""
    parser.add_argument("--condition", type=int, choices=(1, 2, 3), default=1, help="the paper's condition (Table 2)")
    parser.add_argument(
        "--load",
        type=_load_step,
        action="append",
        default=[],
        metavar="KG[@HEIGHT_MM]",
        help="a test weight placed at t = 0, or once the foot is HEIGHT_MM above the pad; repeat for more "
        "(replaces the condition's loads)",
    )
    parser.add_argument(
        "--height", type=number(MIN_HEIGHT_M * 1e3, 1e4, "mm", low_open=False), metavar="MM", help="descent height"
    )
    parser.add_argument(
        "--controller",
        type=controller_name,
        default="pid",
        metavar="NAME",
        help=f"{', '.join(CONTROLLER_NAMES)}, or a policy folder (default pid)",
    )
    add_duration_option(parser, "simulated time (default 30 s)")
    parser.add_argument("--seed", type=seed_number, default=0, help="seed of sensor noise and drift")
    low, high = (1e6 * v for v in CONTROL_PERIOD_RANGE_S)
    parser.add_argument(
        "--control-period",
        type=number(low, high, "us", low_open=False),
        default=CONTROL_PERIOD_S * 1e6,
        metavar="US",
        help="control period (paper: 1000/500/200/100)",
    )
    add_physics_step_option(parser)
    parser.add_argument(
        "--no-imperfections",
        "--ideal",  # its name before 0.4.0
        dest="no_imperfections",
        action="store_true",
        help="switch every imperfection off (an ideal drive, exact sensors, no friction, cogging or drift)",
    )
    parser.add_argument(
        "--randomize", action="store_true", help="a randomised plant (lander, pad, friction, weights) drawn from --seed"
    )
    add_rig_option(parser)
    add_pad_options(parser)


def add_commands(commands) -> None:
    """drop, run, view, reproduce, calibrate and export-mjcf."""
    drop = commands.add_parser(
        "drop",
        help="drop a lander on the pad and compare with the Section 2 closed form",
        description="Drop a lander on the rubber pad in MuJoCo (no field, rig removed) and compare contact time, "
        "restitution, peak deformation and the fitted K, D with the Section 2 spring-damper.",
    )
    drop.add_argument(
        "--mass", type=number(0.0, LOAD_CAPACITY_KG, "kg"), default=LOAD_CAPACITY_KG, metavar="KG", help="lander mass"
    )
    add_pad_options(drop)
    drop.add_argument(
        "--velocity", type=number(0.0, 10.0, "m/s"), default=0.0373, metavar="M_PER_S", help="impact speed"
    )
    drop.add_argument("--json", action="store_true", help="print one JSON object")
    drop.set_defaults(handler=_cmd_drop)

    run = commands.add_parser(
        "run",
        help="run a test condition with a controller and print its metrics",
        description="Run one of the paper's test conditions (or a custom load schedule) in the environment with a "
        "baseline or learned controller, and print the microgravity and landing metrics beside the "
        "ideal-microgravity reference.",
    )
    _add_episode_options(run)
    run.add_argument("--json", action="store_true", help="print one JSON object of metrics")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.add_argument(
        "--plot", metavar="FILE", help="write height, x, acceleration and pad force over time (.png, .pdf, .svg)"
    )
    run.add_argument(
        "--log", metavar="FILE", help="write the run as a rig log: sensor readings and commands (.csv or .parquet)"
    )
    run.add_argument(
        "--video",
        metavar="FILE",
        help="render the run headless with x and the pad force shown (.gif, or .mp4 with imageio-ffmpeg)",
    )
    run.set_defaults(handler=_cmd_run)

    view = commands.add_parser(
        "view",
        help="watch a run live in MuJoCo's viewer (needs a display)",
        description="Run a test condition as `microg run` does and show it in MuJoCo's passive viewer, in real time "
        "or --speed times it, with the time, foot height, x and pad force written and the last 4 s of x and the "
        "pad force plotted; print the run's metrics at its end. Closing the window ends the run.",
    )
    _add_episode_options(view)
    view.add_argument(
        "--speed",
        type=number(1e-3, 1e3, "times real time"),
        default=1.0,
        metavar="X",
        help="playback speed, times real time (default 1; 0.1: ten times slower)",
    )
    view.set_defaults(handler=_cmd_view)

    reproduce = commands.add_parser(
        "reproduce",
        help="reproduce the paper's figures and tables beside this model's (the main job)",
        description="Run conditions 1-3 with the PID baseline, with Table 1's pad and with the calibrated pad, and "
        "write a Markdown report with the equivalents of the paper's Figures 3-7 and Tables 3-6.",
    )
    reproduce.add_argument("--out", default=DEFAULT_REPORT_DIR, metavar="DIR", help="report folder (replaced)")
    add_duration_option(reproduce, "simulated time per run (default 30)")
    reproduce.add_argument("--seed", type=seed_number, default=0, help="seed of sensor noise and drift")
    reproduce.add_argument(
        "--workers",
        type=count(64),
        default=min(usable_cores(), 64),
        metavar="N",
        help="processes running the independent runs at once (default: every usable core)",
    )
    reproduce.add_argument("--quiet", action="store_true", help="no progress bar")
    reproduce.set_defaults(handler=_cmd_reproduce)

    calibrate = commands.add_parser(
        "calibrate",
        help="fit the pad's K and D to the paper's experiments",
        description="Fit the pad's effective stiffness and damping by least squares to the peak deformations and "
        "collision accelerations of Tables 5-6 (the experiments, or the paper's simulation), and print the fit.",
    )
    calibrate.add_argument(
        "--source", choices=("experiment", "simulation"), default="experiment", help="which of the paper's values"
    )
    calibrate.add_argument("--json", action="store_true", help="print one JSON object")
    calibrate.set_defaults(handler=_cmd_calibrate)

    export = commands.add_parser(
        "export-mjcf",
        help="write the resolved rig model (every derived value filled in) as one MJCF file",
        description="Write the rig built from the default parameters as a self-contained MJCF file, with a balanced "
        "'home' keyframe (drive states included) and servo control ranges spanning the screw's stroke, for "
        "mujoco.viewer's Load key and sliders.",
    )
    export.add_argument("output", metavar="FILE", help="MJCF file to write (.xml)")
    export.add_argument(
        "--load",
        type=number(MIN_LOAD_KG, LOAD_CAPACITY_KG / 99.0, "kg", low_open=False),
        action="append",
        default=[],
        metavar="KG",
        help="add a test weight (in the model, held off the lander as at an episode's start)",
    )
    add_rig_option(export)
    add_pad_options(export)
    add_physics_step_option(export)
    export.set_defaults(handler=_cmd_export_mjcf)
