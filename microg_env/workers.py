"""Process pools whose workers start from a fork server, not from the process that asks for them,
and end with that process however it ends.

A process that has stepped a batch holds thread pools (MuJoCo's, the numerical libraries') whose
threads a forked child lacks, and a ``microg compare`` run in a test runner's worker once hung so,
in a forked child building its reference. The fork server is a fresh process that imports
:data:`PRELOAD` once; each worker is forked from it. This module imports nothing of the package, so
a command can start the server first and import the rest while the server does the same.

A killed command used to leave its workers behind for ever, each blocked on a pipe whose other end
it held itself, and with them the fork server and multiprocessing's resource tracker, which wait
for the workers. Each worker now watches a lifeline, a pipe whose write end only the pool's owner
holds: when the owner ends, however it ends (SIGKILL included), the pipe closes and the worker ends
at once; the fork server and the resource tracker then end by themselves. While the owner lives,
its workers end with the pool: one killed while it sends a result leaves the pool waiting for the
rest for ever, so they ignore Ctrl-C (sent to every process of a terminal's job), which is the
owner's to handle. (They keep SIGTERM: a broken pool ends its workers with it.)
"""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.forkserver
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.connection import Connection


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity where the platform has one (a cpuset, a
    pinned test worker; a CPU quota does not show in it), else every core. What "every usable core" means
    for the package's default threads and processes."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


#: What the fork server imports before it forks any worker (the runner brings the environments,
#: the controllers and MuJoCo).
PRELOAD = ("microg_env.rollout.runner",)
#: The signals that stop a command, which a pool's owner takes only once a worker it starts is known
#: to the pool.
DEFERRED = (signal.SIGINT, signal.SIGTERM)
#: Why a pool's workers could not start, and what to do: they import the main script, which starts
#: runs at its top level (and each worker, importing it, a pool of its own)...
UNGUARDED_SCRIPT = (
    "workers > 1 starts worker processes, which run the top-level code of {script}: "
    "put the code that starts the runs under `if __name__ == '__main__':`, or use workers=1"
)
#: ... or which they cannot import (it was read from standard input).
UNREADABLE_SCRIPT = (
    "workers > 1 starts worker processes, which import the main script, and {script} cannot be imported: "
    "save the script to a file, with the code that starts the runs under `if __name__ == '__main__':`, "
    "or use workers=1"
)


@contextlib.contextmanager
def process_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``workers`` processes forked from the fork server (:func:`start_fork_server`), for
    a ``with`` block; its workers end with the block, or with this process, however it ends. A
    block left by an exception (Ctrl-C) drops the tasks no worker has taken. RuntimeError, saying
    what to do, where the workers cannot start: the main script starts runs outside ``if __name__
    == '__main__':`` (each worker, importing it, would start a pool of its own), or it was read
    from standard input."""
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        # A worker importing the main script, which asks for a pool at its top level: it ends
        # quietly, and the script's own process says what to do (multiprocessing's own check,
        # which would stop it, prints a bootstrapping traceback and advice that does not fit).
        raise SystemExit(1)
    script = _main_script()
    if script is not None and not os.path.isfile(script):
        raise RuntimeError(UNREADABLE_SCRIPT.format(script=script))
    start_fork_server()
    lifeline, held = multiprocessing.Pipe(duplex=False)
    pool = _Pool(
        max_workers=workers,
        mp_context=multiprocessing.get_context("forkserver"),
        initializer=_tie_to_owner,
        initargs=(lifeline,),
    )
    try:
        started = pool.submit(os.getpid)  # done at once, unless no worker could start
        yield pool
    except BaseException as error:
        pool.shutdown(cancel_futures=True)
        if isinstance(error, BrokenProcessPool) and script is not None and started.exception() is not None:
            raise RuntimeError(UNGUARDED_SCRIPT.format(script=script)) from None
        raise
    else:
        pool.shutdown()
    finally:
        held.close()
        lifeline.close()


def start_fork_server(also: Sequence[str] = ()) -> None:
    """Start the pools' fork server if it is not running, importing :data:`PRELOAD` and the modules
    ``also`` names: it imports them while this process goes on (a command that will need a pool
    starts it first)."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([*PRELOAD, *also])
    multiprocessing.forkserver.ensure_running()


class _Pool(ProcessPoolExecutor):
    """A pool whose ``submit`` (which may start a worker) takes Ctrl-C and SIGTERM once it returns:
    a worker started and not yet known to the pool was left half-started, and printed a traceback
    once this process had ended."""

    def submit(self, fn, /, *args, **kwargs):
        with _signals_deferred():
            return super().submit(fn, *args, **kwargs)


@contextlib.contextmanager
def _signals_deferred() -> Iterator[None]:
    """Within, on the main thread: SIGINT and SIGTERM wait, and are raised again on leaving."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    previous = {number: signal.signal(number, lambda signum, frame: came.append(signum)) for number in DEFERRED}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)
        for number in came:
            signal.raise_signal(number)


def _main_script() -> str | None:
    """The file a pool's workers run as the main module, as multiprocessing finds it (None where
    they run none: an interactive session, ``python -c``, or a module run by name)."""
    main = sys.modules["__main__"]
    return getattr(main, "__file__", None) if getattr(main, "__spec__", None) is None else None


def _tie_to_owner(lifeline: Connection) -> None:
    """A worker's initializer: leave Ctrl-C to the pool's owner, and end when ``lifeline`` closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_end_with, args=(lifeline,), name="lifeline", daemon=True).start()


def _end_with(lifeline: Connection) -> None:
    lifeline.poll(None)  # nothing is ever sent: this returns when the owner's end closes
    os._exit(1)
