"""A campaign run on Ray: a local instance on this machine's cores, or a cluster by address.

The runs not yet stored (:class:`~microg_env.experiments.store.ResultStore`) are cut into tasks of
specs that share a rig (at most the campaign's ``batch_size``), each a one-CPU Ray task that runs
its specs as rigs of one batch (:func:`~microg_env.experiments.tuning.run_with_retuning`). The driver stores
each task's rows as the task finishes, so an interrupted campaign keeps every finished task and
loses none of its rows; re-running it skips the stored runs (a failed run is tried again). A run
that raises, or a task whose worker dies, is stored with its error. Ctrl-C and SIGTERM stop a
campaign cleanly; a local instance's processes end with the driver, however it ends (:func:`_reaper`).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from microg_env.experiments.campaign import Campaign, Run
from microg_env.experiments.store import FAILED, OK, RESULTS_FILE, ResultStore, result_row
from microg_env.experiments.tuning import run_with_retuning
from microg_env.files import LOCK_FILE, folder_lock, write_text
from microg_env.rollout.runner import RunResult
from microg_env.rollout.spec import RunSpec
from microg_env.workers import usable_cores

#: Seconds to wait for a cluster's head to answer.
CONNECT_TIMEOUT_S = 5.0
#: An HTTP/2 client's connection preface and an empty SETTINGS frame: a Ray head's GCS (a gRPC
#: server) answers them with its own SETTINGS frame (RFC 9113, section 3.4); other services do not.
HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
#: The frame type of HTTP/2's SETTINGS frame, the fourth byte of a frame's header.
HTTP2_SETTINGS = 4
#: Seconds between the driver's looks at a Ctrl-C while it waits for tasks.
WAIT_S = 0.2
#: The campaign file as it was run, in its folder.
CAMPAIGN_COPY = "campaign.json"
#: The signals that stop a campaign where it can stop cleanly: Ctrl-C and SIGTERM (``kill``).
INTERRUPTS = (signal.SIGINT, signal.SIGTERM)
#: Seconds between the looks for the processes a local Ray instance starts.
WATCH_S = 0.5
#: The variable in the environment of the processes of a local Ray instance that a campaign starts.
OWNER = "MICROG_CAMPAIGN_RAY"
#: The program of a reaper (:func:`_reaper`): it holds a pidfd of each process whose pid comes on a
#: line of its standard input; when that closes, it kills them and the processes (the driver
#: aside) whose environment holds its argument, ``OWNER=...``. Signals sent to the whole process
#: group (Ctrl-C in a terminal) leave it be.
REAPER = """\
import os, signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
driver, held = str(os.getppid()), {}
for line in sys.stdin:
    for pid in set(line.split()) - held.keys():
        try:
            held[pid] = os.pidfd_open(int(pid))
        except OSError:  # ended already
            pass
for fd in held.values():
    try:
        signal.pidfd_send_signal(fd, signal.SIGKILL)
    except ProcessLookupError:
        pass
mark = sys.argv[1].encode()
for pid in set(filter(str.isdigit, os.listdir("/proc"))) - {driver}:
    try:
        with open(f"/proc/{pid}/environ", "rb") as environ:
            if mark in environ.read().split(b"\\0"):
                os.kill(int(pid), signal.SIGKILL)
    except OSError:
        pass
"""


@dataclass(frozen=True)
class CampaignSummary:
    """What a campaign run did: runs in the campaign, run now (ok and failed), skipped as stored."""

    name: str
    runs: int
    done: int
    failed: int
    skipped: int
    folder: Path
    results: Path
    report: Path | None
    wall_s: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "campaign": self.name,
            "runs": self.runs,
            "done": self.done,
            "failed": self.failed,
            "skipped": self.skipped,
            "folder": str(self.folder),
            "results": str(self.results),
            "report": None if self.report is None else str(self.report),
            "wall_s": round(self.wall_s, 1),
        }


def _run_task(specs: list[dict], columns: list[dict]) -> list[dict]:
    """A Ray task: these specs as one batch on one core; their rows (a run that raised: its error)."""
    parsed = [RunSpec.from_dict(spec) for spec in specs]
    rows: list[dict | None] = [None] * len(parsed)
    for batch in run_with_retuning(parsed, workers=1):
        for i, result in batch:
            rows[i] = result_row(result, columns[i])
    return rows


def tasks_of(runs: Sequence[Run], batch_size: int) -> list[list[Run]]:
    """``runs`` cut into tasks: specs sharing a compiled model, at most ``batch_size`` each, equal sizes."""
    groups: dict[str, list[Run]] = {}
    for run in runs:
        groups.setdefault(run.spec.batch_key, []).append(run)
    tasks = []
    for members in groups.values():
        count = math.ceil(len(members) / batch_size)
        size = math.ceil(len(members) / count)
        tasks += [members[k : k + size] for k in range(0, len(members), size)]
    return tasks


def execute(
    campaign: Campaign,
    folder: str | os.PathLike,
    address: str | None = None,
    num_cpus: int | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> CampaignSummary:
    """Run ``campaign``'s missing runs on Ray and store them in ``folder``; ``on_progress(runs done,
    runs to do)`` as tasks finish. Ctrl-C or SIGTERM (a KeyboardInterrupt) stops the tasks still
    out, keeps every stored row, writes the table of what is stored and raises KeyboardInterrupt.
    One process at a time writes a folder: a second is refused (ValueError) while the first runs.
    A start that fails before Ray answers leaves no new folder behind."""
    folder = Path(folder)
    check_folder(campaign, folder)
    new, locked = not folder.exists(), False
    try:
        with folder_lock(folder, "campaign folder"):
            locked = True
            return _execute(campaign, folder, address, num_cpus, on_progress)
    except BaseException:
        # A new folder holding only this driver's lock (a refused driver touches nothing)
        if new and locked and folder.is_dir() and [p.name for p in folder.iterdir()] == [LOCK_FILE]:
            shutil.rmtree(folder, ignore_errors=True)
        raise


def _execute(campaign, folder, address, num_cpus, on_progress) -> CampaignSummary:
    import ray

    start = time.perf_counter()
    store = ResultStore(folder)
    runs = campaign.runs()
    stored = store.statuses()
    todo = [run for run in runs if stored.get(run.spec.hash) != OK]
    skipped = len(runs) - len(todo)
    done = failed = 0
    local = bool(todo) and address is None and not ray.is_initialized()
    # From Ray's start to the end of its shutdown, Ctrl-C and SIGTERM set a flag: the campaign
    # stops at its next look, and the shutdown and the table are never cut short.
    with _interrupt_flag() as interrupted, _reaper(local) as starting:
        session = None  # the folder of the local Ray instance this campaign starts (its logs), removed after
        if todo and not ray.is_initialized():  # before anything is written
            with starting():
                context = _start_ray(address, num_cpus)
            if address is None:
                session = getattr(context, "address_info", {}).get("session_dir")
        try:
            if interrupted.is_set():  # during Ray's start: nothing is written
                raise KeyboardInterrupt
            write_text(folder / CAMPAIGN_COPY, json.dumps(asdict(campaign), indent=2) + "\n")
            if todo:
                remote = ray.remote(num_cpus=1, max_retries=0)(_run_task)
                pending = {}
                for task in tasks_of(todo, campaign.batch_size):
                    ref = remote.remote([run.spec.as_dict() for run in task], [run.columns for run in task])
                    pending[ref] = task
                while pending:
                    ready, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_S)
                    for ref in ready:
                        task = pending.pop(ref)
                        try:
                            rows = ray.get(ref)
                        except Exception as error:  # the worker died or the task could not run: record it
                            message = f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
                            rows = [result_row(RunResult(run.spec, None, message), run.columns) for run in task]
                        store.write(rows)
                        failed += sum(row["status"] == FAILED for row in rows)
                        done += len(rows)
                        if on_progress is not None:
                            on_progress(len(rows), len(todo))
                    if interrupted.is_set():
                        raise KeyboardInterrupt
        finally:
            if todo:
                # Ends the driver's job: Ray kills the job's workers, so the tasks still out stop (a
                # cluster given by --address runs on). No ray.cancel: cancelling a task whose reply is
                # already on its way trips a check in Ray's task manager and kills the driver.
                ray.shutdown()
            _finish(store, runs, folder)
            if session is not None:
                shutil.rmtree(session, ignore_errors=True)
    report = None
    if campaign.report is not None:
        from microg_env.experiments.studies import write_study

        report = write_study(campaign, store.table([run.spec.hash for run in runs]), folder)
    return CampaignSummary(
        campaign.name,
        len(runs),
        done - failed,
        failed,
        skipped,
        folder,
        folder / RESULTS_FILE,
        report,
        time.perf_counter() - start,
    )


def _start_ray(address: str | None, num_cpus: int | None) -> Any:
    """``ray.init`` (no ``address``: an instance of its own, never a cluster found on the machine)
    without the SIGTERM handler it puts in, which exits wherever the driver is (inside Ray's wait,
    with a dump of Ray's stack): the caller's handler stays, and a SIGTERM during the start raises
    KeyboardInterrupt. Ray's context."""
    import ray

    handler = signal.getsignal(signal.SIGTERM)
    try:
        return ray.init(
            address=address or "local",
            num_cpus=None if address else (usable_cores() if num_cpus is None else num_cpus),
            include_dashboard=False,
            log_to_driver=False,
            logging_level="ERROR",
            configure_logging=True,
        )
    except SystemExit as error:  # Ray's handler: SIGTERM came during the start
        if error.code != signal.SIGTERM:
            raise
        ray.shutdown()
        raise KeyboardInterrupt from None
    finally:
        if handler is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, handler)


@contextlib.contextmanager
def _reaper(local: bool) -> Iterator[Callable[[], contextlib.AbstractContextManager]]:
    """For a ``local`` Ray instance: a process that kills the instance's processes when the block
    ends, or when this process ends, however it ends (SIGKILL included). Ray ties the GCS server,
    raylet and workers to the driver, but its dashboard and runtime-env agents outlived a killed
    driver by a minute (reporting the raylet's death to the dead GCS server), and workers still
    starting lingered too. Yields ``starting``, the context to start Ray in. A thread tells the
    reaper of the instance's processes as they start: each new descendant of this process while Ray
    starts, then each new child of those; the reaper holds pidfds, which a reused pid cannot fool.
    Those started since the thread's last look carry :data:`OWNER` in their environment, which the
    reaper looks for too. Linux only (elsewhere, and for a cluster, nothing is watched)."""
    if not local or not hasattr(os, "pidfd_open") or not os.path.isdir("/proc"):
        yield contextlib.nullcontext
        return
    mark = uuid.uuid4().hex
    reaper = subprocess.Popen(
        [sys.executable, "-c", REAPER, f"{OWNER}={mark}"], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True
    )
    others = set(_parents())  # the processes there before Ray's
    started, ended = threading.Event(), threading.Event()

    def watch() -> None:
        ours: set[int] = set()
        while True:
            parents = _parents()
            while True:  # the children of ours, and of theirs (and of this process, while Ray starts)
                roots = ours if started.is_set() else ours | {os.getpid()}
                new = {pid for pid, parent in parents.items() if parent in roots} - ours - others
                if not new:
                    break
                ours |= new
                reaper.stdin.write(" ".join(map(str, new)) + "\n")
            reaper.stdin.flush()
            if ended.wait(WATCH_S):
                return

    @contextlib.contextmanager
    def starting() -> Iterator[None]:
        os.environ[OWNER] = mark
        try:
            yield
        finally:
            del os.environ[OWNER]
            started.set()

    watcher = threading.Thread(target=watch, name="ray-processes", daemon=True)
    watcher.start()
    try:
        yield starting
    finally:
        ended.set()
        watcher.join()
        reaper.stdin.close()
        reaper.wait()


def _parents() -> dict[int, int]:
    """Every process's parent, from /proc: pid -> parent's pid."""
    parents = {}
    for name in filter(str.isdigit, os.listdir("/proc")):
        with contextlib.suppress(OSError, IndexError), open(f"/proc/{name}/stat", "rb") as stat:  # or ended
            parents[int(name)] = int(stat.read().rsplit(b")", 1)[1].split()[1])
    return parents


@contextlib.contextmanager
def _interrupt_flag() -> Iterator[threading.Event]:
    """Within: SIGINT (Ctrl-C) and SIGTERM set the yielded event instead of raising
    KeyboardInterrupt, and the caller raises it where it chooses; on leaving, the handlers are
    restored, and KeyboardInterrupt raised if the event is set. Ray's ``wait`` checks for signals
    itself and can drop the KeyboardInterrupt when a task finishes at the same moment (the campaign
    then ran on to the end); a flag cannot be dropped. Off the main thread, where Python allows no
    handler, it stays unset."""
    interrupted = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield interrupted
        return
    previous = {number: signal.signal(number, lambda signum, frame: interrupted.set()) for number in INTERRUPTS}
    try:
        yield interrupted
    finally:
        for number, handler in previous.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)
    if interrupted.is_set():
        raise KeyboardInterrupt


def check_folder(campaign: Campaign, folder: Path) -> None:
    """ValueError if ``folder`` holds another campaign's results (its name differs), or a record of
    its campaign that cannot be read (naming the file and the fault)."""
    record = folder / CAMPAIGN_COPY
    if record.is_file():
        try:
            recorded = json.loads(record.read_text(encoding="utf-8"))
            if not isinstance(recorded, dict) or not isinstance(recorded.get("name"), str):
                raise ValueError("it names no campaign")
        except (ValueError, OSError) as error:
            raise ValueError(
                f"--out {str(folder)!r}: its campaign record {str(record)!r} cannot be read ({error}); "
                "restore it, or give another folder"
            ) from None
        name = recorded["name"]
        if name != campaign.name:
            raise ValueError(
                f"--out {str(folder)!r} holds the results of campaign {name!r}, not {campaign.name!r}; "
                "give another folder"
            )


def check_address(address: str) -> None:
    """Before Ray is imported: raise ConnectionError unless a gRPC server, as a Ray head's GCS is,
    answers at ``address`` (HOST:PORT; ``auto`` finds the cluster this machine started), so a wrong
    address or another service there fails in seconds, not after Ray's minutes of retries (a head
    that serves gRPC over TLS only is refused too: connect to it with Ray's own tools); and
    join a cluster that uses token authentication (Ray's default for ``ray start``) with the token
    Ray keeps in ~/.ray/auth_token, as ``ray start`` does."""
    if address != "auto":
        host, _, port = address.removeprefix("ray://").rpartition(":")
        if host.startswith("[") and host.endswith("]"):  # an IPv6 address, [::1]:6379
            host = host[1:-1]
        if not host or not port.isdigit():
            raise ValueError(f"--address {address!r}: give HOST:PORT (the head's GCS port) or 'auto'")
        try:
            connection = socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S)
        except OSError as error:
            raise ConnectionError(f"nothing answers at {address} ({error.strerror or error})") from None
        header = b""
        with connection:
            try:
                connection.sendall(HTTP2_PREFACE)
                while len(header) < 4 and (chunk := connection.recv(9 - len(header))):
                    header += chunk
            except OSError:  # a timeout or a reset: no gRPC server
                pass
        if len(header) < 4 or header[3] != HTTP2_SETTINGS:
            raise ConnectionError(f"the service at {address} is not a Ray cluster (it does not answer as gRPC does)")
    if "RAY_AUTH_MODE" not in os.environ and (Path.home() / ".ray" / "auth_token").is_file():
        os.environ["RAY_AUTH_MODE"] = "token"


def _finish(store: ResultStore, runs: Sequence[Run], folder: Path) -> None:
    if store.parts.exists():
        store.export(folder / RESULTS_FILE, [run.spec.hash for run in runs])
