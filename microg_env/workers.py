"""Process pools whose workers start from a fork server, not from the process that asks for them.

A process that has stepped a batch holds thread pools (MuJoCo's, the numerical libraries') whose
threads a forked child lacks, and a ``microg compare`` run in a test runner's worker once hung so,
in a forked child building its reference. The fork server is a fresh process that imports
:data:`PRELOAD` once; each worker is forked from it. This module imports nothing of the package, so
a command can start the server first and import the rest while the server does the same.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor

#: What the fork server imports before it forks any worker (the runner brings the environments,
#: the controllers and MuJoCo).
PRELOAD = ("microg_env.rollout.runner",)


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes forked from the fork server (:func:`start_fork_server`)."""
    start_fork_server()
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("forkserver"))


def start_fork_server(also: Sequence[str] = ()) -> None:
    """Start the pools' fork server if it is not running, importing :data:`PRELOAD` and the modules
    ``also`` names: it imports them while this process goes on (a command that will need a pool
    starts it first)."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([*PRELOAD, *also])
    multiprocessing.forkserver.ensure_running()
