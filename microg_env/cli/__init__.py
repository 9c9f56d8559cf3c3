"""The ``microg`` command.

Every user error (a bad option or value, an unwritable output) prints one line to stderr naming
the option and exits with code 2, before any work is done; Ctrl-C, and SIGTERM (``kill``'s
default) likewise, stops the command with its cleanup (no process of its own left behind), prints
one line and exits with 130; output piped into a closed reader (``| head``) ends quietly. The
commands live in :mod:`microg_env.cli.rig` (the rig and the paper), :mod:`microg_env.cli.learning`
(learned controllers) and :mod:`microg_env.cli.logs` (a rig's logs); what they share in
:mod:`microg_env.cli.common`.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence

from microg_env.cli.common import Parser, UsageError, one_line
from microg_env.version import __version__
from microg_env.workers import start_fork_server, usable_cores

__all__ = ["UsageError", "build_parser", "main"]

#: Commands whose process pool's fork server starts before the commands' modules are imported,
#: and what it imports besides the runner: it imports while this process does.
POOLED_COMMANDS = {"reproduce": ("microg_env.paper.figures",), "identify": ("microg_env.experiments.identify",)}


def build_parser() -> argparse.ArgumentParser:
    from microg_env.cli import campaign, learning, logs, rig  # after a pooled command's fork server started

    parser = Parser(prog="microg", description="MuJoCo model of the QZS microgravity landing rig (Jia et al. 2024).")
    parser.add_argument("--version", action="version", version=f"microg {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    rig.add_commands(commands)
    learning.add_commands(commands)
    logs.add_commands(commands)
    campaign.add_commands(commands)
    return parser


def _check_top_level(argv: list[str]) -> None:
    """An option before the command: name it (argparse would only say the command is missing)."""
    if argv and argv[0].startswith("-") and argv[0] not in ("-h", "--help", "--version"):
        raise UsageError(f"microg: error: unrecognized option {argv[0]!r}; give a command first (microg --help)")


def _start_pool(argv: list[str]) -> None:
    """Start the fork server of a pooled command (:data:`POOLED_COMMANDS`) that will run on more
    than one process (``--workers``, default every usable core); not for its help, and not where its
    options are bad (its own parser says so)."""
    if argv[0] not in POOLED_COMMANDS:
        return
    options = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    options.add_argument("-h", "--help", action="store_true")
    options.add_argument("--workers")
    try:
        known = options.parse_known_args(argv[1:])[0]
        pooled = usable_cores() > 1 if known.workers is None else int(known.workers) != 1
    except (argparse.ArgumentError, ValueError):
        return
    if pooled and not known.help:
        start_fork_server(POOLED_COMMANDS[argv[0]])


@contextlib.contextmanager
def _sigterm_as_ctrl_c() -> Iterator[None]:
    """Within, on the main thread: SIGTERM raises KeyboardInterrupt, as Ctrl-C does (by default it
    ends the process at once, skipping the cleanup that Ctrl-C runs)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``microg`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:  # a bare `microg`: what it can do, not an error
        build_parser().print_help()
        return 0
    try:
        with _sigterm_as_ctrl_c():
            _check_top_level(argv)
            _start_pool(argv)
            args = build_parser().parse_args(argv)
            args.argv = argv
            return args.handler(args)
    except UsageError as error:
        print(one_line(str(error)), file=sys.stderr)
        return 2
    except ValueError as error:
        print(f"microg: error: {one_line(str(error))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: one line, the shell's code for Ctrl-C, no traceback
        print("microg: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (| head): stop quietly, as Python's documentation recommends.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
