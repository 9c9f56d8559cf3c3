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
from pathlib import Path

from microg_env.drop import DropReport, drop_test
from microg_env.params import RigParams


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
    report = drop_test(args.mass, args.stiffness, args.damping, args.velocity)
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
    from microg_env.model import build_spec

    spec, _ = build_spec(RigParams(), tuple(args.load))
    spec.compile()
    write_atomically(Path(args.output), spec.to_xml())
    print(f"wrote {args.output}")
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
    drop.add_argument(
        "--stiffness", type=_float, default=defaults.pad.stiffness_n_per_m, metavar="N_PER_M", help="pad stiffness K"
    )
    drop.add_argument(
        "--damping", type=_float, default=defaults.pad.damping_n_s_per_m, metavar="N_S_PER_M", help="pad damping D"
    )
    drop.add_argument("--velocity", type=_float, default=0.0373, metavar="M_PER_S", help="impact speed")
    drop.add_argument("--json", action="store_true", help="print one JSON object")
    drop.set_defaults(handler=_cmd_drop)

    export = commands.add_parser(
        "export-mjcf",
        help="write the resolved rig model (every derived value filled in) as one MJCF file",
        description="Write the rig built from the default parameters as a self-contained MJCF file.",
    )
    export.add_argument("output", metavar="FILE", help="MJCF file to write")
    export.add_argument("--load", type=_float, action="append", default=[], metavar="KG", help="add a test weight")
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
