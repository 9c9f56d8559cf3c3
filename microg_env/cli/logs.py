"""The ``microg`` commands on a rig's logs: ``replay`` and ``identify`` (``run --log`` writes one)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from microg_env.cli.common import (
    add_physics_step_option,
    add_rig_option,
    comma_list,
    count,
    number,
    progress_bar,
)
from microg_env.logs import DEFAULT_WINDOW_S
from microg_env.workers import usable_cores

#: Figure formats ``replay --plot`` writes.
PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def _logs(paths: list[str]) -> list:
    from microg_env.logs import read_log

    try:
        return [read_log(path) for path in paths]
    except ValueError as error:
        raise ValueError(f"LOG: {error}") from None


def _rig(args: argparse.Namespace):
    """The rig of ``--rig`` (the paper's without it), and its file as read (None without)."""
    from microg_env.params import RigParams
    from microg_env.rigs import read_rig_option

    if args.rig is None:
        return RigParams(), None
    rig = read_rig_option(args.rig, "--rig")
    return rig.params, rig


def _named(error: ValueError, logs: list[str]) -> ValueError:
    """A replay's error named by what caused it: ``--window``, or the log (its period, rows, schedule)."""
    message = str(error)
    if message.startswith("window_s"):
        return ValueError(f"--window: {message}")
    if message.startswith("log "):
        return ValueError(f"LOG: {message}")
    return ValueError(f"LOG {', '.join(map(repr, logs))}: {message}")


def _cmd_replay(args: argparse.Namespace) -> int:
    from microg_env.experiments.identify import reading_noise
    from microg_env.files import check_output_file
    from microg_env.rollout.replay import replay
    from microg_env.rollout.replay import rms as replay_rms

    (log,) = _logs([args.log])
    params, _ = _rig(args)
    plot = None if args.plot is None else check_output_file(args.plot, "--plot", PLOT_SUFFIXES)
    if plot is not None:
        from microg_env.analysis.plots import require_matplotlib

        require_matplotlib()
    try:
        result = replay(log, params, args.window, args.physics_step / 1e6)
    except ValueError as error:
        raise _named(error, [args.log]) from None
    residuals, noise = result.residuals(), reading_noise(params)
    rms = replay_rms(residuals)
    summary = {
        "log": args.log,
        "rows": log.rows,
        "rows_replayed": int(result.encoder_m.size),
        "ended": result.ended,
        "window_s": result.window_rows * log.control_period_s,
        "rms_m": rms,
        "reading_sd_m": noise,
        "max_abs_m": {name: float(abs(r).max()) for name, r in residuals.items()},
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"{args.log}: {log.rows} rows at {log.control_period_s * 1e6:g} us; replayed {summary['rows_replayed']}"
            f"{'' if result.ended is None else f' (the model left the log: {result.ended})'}, in windows of "
            f"{summary['window_s']:g} s"
        )
        print(f"{'channel':<10}{'residual RMS [nm]':>20}{'reading SD [nm]':>18}{'max [nm]':>12}")
        for name in residuals:
            print(
                f"{name:<10}{rms[name] * 1e9:>20.3f}{noise[name] * 1e9:>18.3f}{summary['max_abs_m'][name] * 1e9:>12.1f}"
            )
    if plot is not None:
        from microg_env.analysis.plots import plot_replay

        model = {"ruler_m": result.ruler_m[0], "encoder_m": result.encoder_m}
        model |= {f"{name}_residual": r for name, r in residuals.items()}
        plot_replay(log.columns["time_s"], log.columns, model, f"replay of {Path(args.log).name}", plot)
        if not args.json:
            print(f"wrote {plot}")
    return 0


def _cmd_identify(args: argparse.Namespace) -> int:
    from microg_env.experiments.identify import FIT_SCALES, identify
    from microg_env.files import check_output_file
    from microg_env.rigs import RigFile, write_rig

    logs = _logs(args.logs)
    params, start = _rig(args)
    out = check_output_file(args.out, "--out", (".toml",))
    if args.fit is not None:
        unknown = [name for name in args.fit if name not in FIT_SCALES]
        if unknown:
            raise ValueError(f"--fit: {unknown[0]!r} is not one of {', '.join(FIT_SCALES)}")
    with progress_bar("identify", args.quiet, unit="point") as bar:
        try:
            result = identify(
                logs, params, args.fit, args.window, args.physics_step / 1e6, workers=args.workers,
                on_point=lambda: bar.update(1),
            )  # fmt: skip
        except ValueError as error:
            raise _named(error, args.logs) from None
    unseen = [name for name, half in result.half_widths.items() if not math.isfinite(half)]
    if unseen:
        raise ValueError(
            f"--fit: the logs do not identify {', '.join(unseen)} (the residuals do not move with it); leave it out"
        )
    names = ", ".join(Path(path).name for path in args.logs)
    overrides = dict(start.overrides) if start is not None else {}
    sources = dict(start.sources) if start is not None else {}
    for name, value in result.values.items():
        overrides[name] = value
        sources[name] = f"microg identify from {names}: +-{result.half_widths[name]:.3g} (95 %)"
    description = start.description if start is not None and start.description else f"identified from {names}"
    write_rig(RigFile(overrides, sources, description), out)
    if args.json:
        print(json.dumps({"values": result.values, "half_widths_95": result.half_widths, "start": result.start,
                          "rms_m": result.rms, "reading_sd_m": result.noise, "iterations": result.iterations,
                          "out": str(out)}, indent=2))  # fmt: skip
        return 0
    print(f"{'parameter':<34}{'start':>14}{'identified':>14}{'95 % interval':>16}")
    for name, value in result.values.items():
        print(
            f"{name:<34}{result.start[name]:>14.6g}{value:>14.6g}{'+-' + format(result.half_widths[name], '.3g'):>16}"
        )
    for name, rms in result.rms.items():
        print(f"{name} residual RMS {rms * 1e9:.3f} nm (reading SD {result.noise[name] * 1e9:.3f} nm)")
    print(f"wrote {out}")
    return 0


def add_commands(commands) -> None:
    """replay and identify."""
    window = {
        "type": number(1e-3, 10.0, "s"),
        "default": DEFAULT_WINDOW_S,
        "metavar": "S",
        "help": f"replay window: the lander's state is set from the log at each window's start (default "
        f"{DEFAULT_WINDOW_S:g})",
    }
    replay = commands.add_parser(
        "replay",
        help="run a rig log's commands on the model and compare its ruler and encoder with the log's",
        description="Run the drive commands of LOG (docs/model.md, Rig logs) on the model, in windows whose start "
        "sets the lander's state from the log, and print the residuals of the ruler and the encoder beside the "
        "readings' standard deviations.",
    )
    replay.add_argument("log", metavar="LOG", help="a rig log (.csv or .parquet)")
    add_rig_option(replay)
    replay.add_argument("--window", **window)
    add_physics_step_option(replay)
    replay.add_argument("--plot", metavar="FILE", help="write the log beside the model, and the residuals")
    replay.add_argument("--json", action="store_true", help="print one JSON object")
    replay.set_defaults(handler=_cmd_replay)

    identify = commands.add_parser(
        "identify",
        help="fit a rig's unknown parameters to its logs and write a rig file",
        description="Fit the drive's speed loop, torque filter and cogging, Eq. 17's residual stiffness, the "
        "ruler's zero and, where a log lands, the pad's K and D, by least squares on the replay's residuals, "
        "with 95 % intervals; write the rig file --rig's values with the fitted ones.",
    )
    identify.add_argument("logs", nargs="+", metavar="LOG", help="rig logs (.csv or .parquet) of one rig")
    identify.add_argument("--out", required=True, metavar="RIG.toml", help="the rig file to write")
    add_rig_option(identify)
    identify.add_argument(
        "--fit", type=comma_list, metavar="A,B,...", help="the parameters to fit (default: all it can; docs/model.md)"
    )
    identify.add_argument("--window", **window)
    add_physics_step_option(identify)
    identify.add_argument(
        "--workers",
        type=count(64),
        default=min(usable_cores(), 64),
        metavar="N",
        help="processes replaying the points of a Jacobian at once (default: every usable core)",
    )
    identify.add_argument("--json", action="store_true", help="print one JSON object")
    identify.add_argument("--quiet", action="store_true", help="no progress bar")
    identify.set_defaults(handler=_cmd_identify)
