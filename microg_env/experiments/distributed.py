"""A campaign run on Ray: a local instance on this machine's cores, or a cluster by address.

The runs not yet stored (:class:`~microg_env.experiments.store.ResultStore`) are cut into tasks of
specs that share a rig (at most the campaign's ``batch_size``), each a one-CPU Ray task that runs
its specs as rigs of one batch (:func:`~microg_env.experiments.tuning.run_with_retuning`). The driver stores
each task's rows as the task finishes, so an interrupted campaign keeps every finished task and
loses none of its rows; re-running it skips the stored runs (a failed run is tried again). A run
that raises, or a task whose worker dies, is stored with its error.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import signal
import socket
import threading
import time
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
    runs to do)`` as tasks finish. A KeyboardInterrupt stops the tasks still out, keeps every
    stored row, writes the table of what is stored and re-raises. One process at a time writes a
    folder: a second is refused (ValueError) while the first runs. A start that fails before Ray
    answers leaves no new folder behind."""
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
    session = None  # the folder of the local Ray instance this campaign starts (its logs), removed after
    if todo and not ray.is_initialized():  # before anything is written
        context = ray.init(  # "local": an instance of its own, never a cluster found on the machine
            address=address or "local",
            num_cpus=None if address else num_cpus,
            include_dashboard=False,
            log_to_driver=False,
            logging_level="ERROR",
            configure_logging=True,
        )
        if address is None:
            session = getattr(context, "address_info", {}).get("session_dir")
    write_text(folder / CAMPAIGN_COPY, json.dumps(asdict(campaign), indent=2) + "\n")
    done = failed = 0
    if todo:
        remote = ray.remote(num_cpus=1, max_retries=0)(_run_task)
        pending = {}
        try:
            for task in tasks_of(todo, campaign.batch_size):
                ref = remote.remote([run.spec.as_dict() for run in task], [run.columns for run in task])
                pending[ref] = task
            with _interrupt_flag() as interrupted:
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
            # Ends the driver's job: Ray kills the job's workers, so the tasks still out stop (a
            # cluster given by --address runs on). No ray.cancel: cancelling a task whose reply is
            # already on its way trips a check in Ray's task manager and kills the driver.
            ray.shutdown()
            _finish(store, runs, folder)
            if session is not None:
                shutil.rmtree(session, ignore_errors=True)
    else:
        _finish(store, runs, folder)
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


@contextlib.contextmanager
def _interrupt_flag() -> Iterator[threading.Event]:
    """Within: SIGINT (Ctrl-C) sets the yielded event instead of raising KeyboardInterrupt, and the
    caller raises it where it chooses. Ray's ``wait`` checks for signals itself and can drop the
    KeyboardInterrupt when a task finishes at the same moment (the campaign then ran on to the end);
    a flag cannot be dropped. Off the main thread, where Python allows no handler, it stays unset."""
    interrupted = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield interrupted
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: interrupted.set())
    try:
        yield interrupted
    finally:
        signal.signal(signal.SIGINT, signal.SIG_DFL if previous is None else previous)


def check_folder(campaign: Campaign, folder: Path) -> None:
    """ValueError if ``folder`` holds another campaign's results (its name differs)."""
    record = folder / CAMPAIGN_COPY
    if record.is_file():
        try:
            name = json.loads(record.read_text(encoding="utf-8")).get("name")
        except (ValueError, OSError, AttributeError):
            name = None
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
