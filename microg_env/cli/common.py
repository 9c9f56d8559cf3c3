"""What every ``microg`` command shares: one-line usage errors, option types with bounds, options
naming the errors they cause, the rig and pad options, output-folder checks, the progress bar."""

from __future__ import annotations

import argparse
import difflib
import math
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path

from microg_env.files import check_writable
from microg_env.interface import selects_policy
from microg_env.params import PAD_NAMES, PHYSICS_STEP_RANGE_S, PHYSICS_STEP_S
from microg_env.scenarios import MAX_DURATION_S, MIN_DURATION_S

#: Seeds accepted on the command line (NumPy's and Gymnasium's seeds are non-negative).
MAX_SEED = 2**32 - 1


class UsageError(Exception):
    """A bad command line; reported on one line with exit code 2."""


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # argparse would print the whole usage first
        raise UsageError(f"{self.prog}: error: {one_line(message)}")

    def parse_args(self, args=None, namespace=None):
        """argparse's, and an unknown option comes with the closest option of its command."""
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            command = getattr(parsed, "command", None)
            parser = self._subparsers._group_actions[0].choices.get(command, self) if self._subparsers else self
            name = extras[0].split("=")[0]
            close = difflib.get_close_matches(name, list(parser._option_string_actions), n=1, cutoff=0.6)
            hint = f"; did you mean {close[0]}?" if close and name.startswith("-") else ""
            self.error(f"unrecognized arguments: {' '.join(extras)}{hint}")
        return parsed


def one_line(message: str) -> str:
    """A message on one line (a value with a newline in it must not split the error)."""
    return message.replace("\r", "\\r").replace("\n", "\\n")


#: The options of ``microg run`` (and ``view``, ``export-mjcf``) by the fields their errors name
#: (:class:`microg_env.validate.FieldError`): a field's whole name, or its last part
#: (``PadParams.stiffness_n_per_m`` is ``stiffness_n_per_m``).
RUN_OPTIONS = {
    "descent_height_m": "--height",
    "loads": "--load",
    "loads_kg": "--load",
    "LoadStep.mass_kg": "--load",
    "LoadStep.height_m": "--load",
    "duration_s": "--duration",
    "control_period_s": "--control-period",
    "physics_step_s": "--physics-step",
    "stiffness_n_per_m": "--stiffness",
    "damping_n_s_per_m": "--damping",
}


def run_options(args: argparse.Namespace) -> dict[str, str]:
    """:data:`RUN_OPTIONS` for this command line: a pad value that ``--rig``'s file gave (no pad
    option given) is blamed on ``--rig``."""
    if getattr(args, "rig", None) is None or args.pad != "paper":
        return RUN_OPTIONS
    given = {"stiffness_n_per_m": args.stiffness, "damping_n_s_per_m": args.damping}
    return RUN_OPTIONS | {name: "--rig" for name, value in given.items() if value is None}


#: The same for ``microg drop``, whose errors may name several options.
DROP_OPTIONS = {
    "mass": "--mass",
    "mass_kg": "--mass",
    "stiffness": "--stiffness",
    "stiffness_n_per_m": "--stiffness",
    "damping": "--damping",
    "damping_n_s_per_m": "--damping",
    "velocity": "--velocity",
}


def naming(error: ValueError, options: Mapping[str, str], every: bool = False) -> ValueError:
    """``error`` prefixed with the option that set its first field that has one (``every``: the
    options of all its fields); an error naming no field, or already naming its option, as it is."""
    message = str(error)
    if message.startswith("--"):
        return error
    fields = [name.split(" ")[0] for name in getattr(error, "fields", ())]  # "Scenario.loads item": the loads
    named = [options.get(name, options.get(name.rpartition(".")[2])) for name in fields]
    named = list(dict.fromkeys(option for option in named if option))
    if not every:
        named = named[:1]
    return ValueError(f"{', '.join(named)}: {message}") if named else error


def number(low: float, high: float, unit: str, low_open: bool = True) -> Callable[[str], float]:
    """An argparse type: a finite number in (low, high] (or [low, high]) in ``unit``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        below = value <= low if low_open else value < low
        if not math.isfinite(value) or below or value > high:
            bracket = "(" if low_open else "["
            raise argparse.ArgumentTypeError(f"must be in {bracket}{low:g}, {high:g}] {unit}, got {text!r}")
        return value

    return parse


def seed_number(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, {MAX_SEED}], got {text!r}")
    return value


def count(high: float = 1e12) -> Callable[[str], int]:
    """An argparse type: a whole number in [1, high], also written 1e6."""

    def parse(text: str) -> int:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if not (math.isfinite(value) and value.is_integer() and 1 <= value <= high):
            raise argparse.ArgumentTypeError(f"must be an integer in [1, {high:g}], got {text!r}")
        return int(value)

    return parse


def comma_list(text: str) -> list[str]:
    """A comma-separated list (spaces around the commas allowed), with no empty or repeated items
    (a repeat would count its runs twice in every mean)."""
    items = [item.strip() for item in text.split(",")]
    if not all(items):
        raise argparse.ArgumentTypeError(f"empty item in {text!r}")
    repeated = next((item for i, item in enumerate(items) if item in items[:i]), None)
    if repeated is not None:
        raise argparse.ArgumentTypeError(f"{repeated!r} is given twice in {text!r}")
    return items


def check_writable_folder(path: str, option: str) -> None:
    """``path`` is a folder this user may write in, or can be made one (nothing is created here)."""
    if not path.strip():
        raise ValueError(f"{option}: the folder name is empty")
    folder = Path(os.path.abspath(path))
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{option} {path!r}: {str(existing)!r} is not a folder")
    check_writable(existing, option, path)


class ProgressStream:
    """A progress bar's stream that goes quiet when its reader goes away (``2>&1 | head``): the
    work and its results are not lost to a closed pipe."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self.open = True

    def write(self, text: str) -> None:
        if self.open:
            try:
                self.stream.write(text)
            except BrokenPipeError:
                self.open = False

    def flush(self) -> None:
        if self.open:
            try:
                self.stream.flush()
            except BrokenPipeError:
                self.open = False


def progress_bar(desc: str, quiet: bool, total: float = 0, unit: str = "step"):
    """tqdm's bar on stderr (``--quiet``: none), quiet once its reader goes away."""
    from tqdm import tqdm

    stream = ProgressStream(sys.stderr)
    return tqdm(total=total, unit=unit, unit_scale=unit == "step", desc=desc, file=stream, disable=quiet)


def pad_from_options(args: argparse.Namespace):
    """The pad of ``--pad``, with ``--stiffness`` and ``--damping`` replacing its K and D."""
    from microg_env.paper.calibration import pad_params

    pad = pad_params(args.pad)
    try:
        if args.stiffness is not None:
            pad = replace(pad, stiffness_n_per_m=args.stiffness)
        if args.damping is not None:
            pad = replace(pad, damping_n_s_per_m=args.damping)
    except ValueError as error:
        raise naming(error, RUN_OPTIONS) from None
    return pad


def add_rig_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rig",
        metavar="RIG.toml",
        help="a rig file: the parameters in which your rig differs from the paper's (docs/model.md, Rig files)",
    )


def rig_overrides(args: argparse.Namespace) -> dict[str, object]:
    """The overrides of ``--rig``'s file by dotted path (none without it), its pad's K and D
    replaced by ``--pad``'s, then by ``--stiffness`` and ``--damping``, where one is given; a bad
    file is named with the option."""
    overrides: dict[str, object] = {}
    if getattr(args, "rig", None) is not None:
        from microg_env.rigs import read_rig_option

        overrides = read_rig_option(args.rig, "--rig").overrides
    if not hasattr(args, "pad"):
        return overrides
    given = {"stiffness_n_per_m": args.stiffness, "damping_n_s_per_m": args.damping}
    pad = {f"pad.{name}": value for name, value in given.items() if value is not None}
    if args.pad != "paper":
        named = pad_from_options(args)
        overrides |= {f"pad.{name}": getattr(named, name) for name in ("stiffness_n_per_m", "damping_n_s_per_m")}
    elif pad:
        pad_from_options(args)  # the options' own checks, named
    return overrides | pad


def add_pad_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--pad",
        choices=PAD_NAMES,
        default="paper",
        help="the pad: Table 1's K and D (paper), fitted to the experiments (calibrated) or to the paper's "
        "simulation (paper-simulation)",
    )
    parser.add_argument(
        "--stiffness", type=number(0.0, 1e12, "N/m"), metavar="N_PER_M", help="pad stiffness K (default: --pad's)"
    )
    parser.add_argument(
        "--damping", type=number(0.0, 1e12, "N s/m"), metavar="N_S_PER_M", help="pad damping D (default: --pad's)"
    )


def add_duration_option(parser: argparse.ArgumentParser, help_text: str) -> None:
    duration = number(MIN_DURATION_S, MAX_DURATION_S, "s", low_open=False)
    parser.add_argument("--duration", type=duration, metavar="S", help=help_text)


def add_physics_step_option(parser: argparse.ArgumentParser) -> None:
    low, high = (1e6 * v for v in PHYSICS_STEP_RANGE_S)
    parser.add_argument(
        "--physics-step",
        type=number(low, high, "us", low_open=False),
        default=PHYSICS_STEP_S * 1e6,
        metavar="US",
        help=f"physics step (default {PHYSICS_STEP_S * 1e6:g}, chosen by a convergence study)",
    )


def controller_name(text: str) -> str:
    """An argparse type: a controller's name or a policy folder; a name that is neither is refused
    before the controllers import, a policy's folder is read and checked now."""
    try:
        if selects_policy(text):
            from microg_env.controllers.registry import check_controller_name

            check_controller_name(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error).removeprefix("controller ")) from None
    return text
