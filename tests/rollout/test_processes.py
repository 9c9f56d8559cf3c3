"""A killed command leaves no process behind, and runs again whole (issue #44).

``microg reproduce`` and ``microg compare`` run on process pools whose workers fork from a fork
server; ``microg campaign`` on a local Ray instance. Each is killed (SIGKILL; SIGTERM, which the
command line turns into Ctrl-C's KeyboardInterrupt) in a session of its own while its workers run;
no process of that session may be alive 10 s later, and the same command then writes every row
once.
``run_all(workers > 1)`` in a script its workers cannot import says what to do in one line.
"""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

import microg_env
from microg_env.analysis.metrics import RunMetrics
from microg_env.cli import main
from microg_env.experiments.store import ResultStore

#: The tree of the package under test: the commands run from it.
TREE = Path(microg_env.__file__).resolve().parents[1]
MICROG = [sys.executable, "-m", "microg_env.cli"]
ENV = {**os.environ, "PYTHONPATH": str(TREE)}
#: Seconds a killed command's processes get to end.
GRACE_S = 10.0
KILLS = [signal.SIGKILL, signal.SIGTERM]
REPRODUCE = ["reproduce", "--duration", "1", "--workers", "2", "--quiet"]
COMPARE = ["compare", "--controllers", "pid,feedforward", "--scenarios", "condition-2", "--seeds", "2"]
COMPARE += ["--duration", "3", "--workers", "2", "--quiet", "--no-floor"]
CAMPAIGN = """\
name: killed
base: {scenario: condition-2, duration_s: 0.3}
sweep: {controller: [pid, feedforward, pid-dom]}
seeds: {first: 0, count: 4}
batch_size: 1
"""
CAMPAIGN_36 = """\
name: resume-test
base: {scenario: condition-2, duration_s: 0.2}
sweep:
  qzs.guide_friction_n, qzs.guide_static_friction_n: [[0.1, 0.125], [0.3, 0.375], [0.5, 0.625]]
  controller: [pid, feedforward, residual-sac-setpoint]
  control_period_us: [1000, 500]
seeds: {first: 0, count: 2}
batch_size: 4
"""
#: A campaign run by ``distributed.execute`` on a local Ray instance of its own (one CPU), printing
#: its summary and the session folder of each Ray instance it started.
SESSIONS_SEEN = """\
import json, sys, ray
from microg_env.experiments import distributed
from microg_env.experiments.campaign import Campaign
sessions, start = [], ray.init
def init(**kwargs):
    context = start(**kwargs)
    sessions.append(context.address_info["session_dir"])
    return context
ray.init = init
summary = distributed.execute(Campaign.load(sys.argv[1]), sys.argv[2], num_cpus=1)
print(json.dumps({"skipped": summary.skipped, "failed": summary.failed, "sessions": sessions}))
"""
UNGUARDED = """\
from microg_env.rollout.runner import run_all
from microg_env.rollout.spec import RunSpec

run_all([RunSpec(duration_s=0.1, seed=seed) for seed in range(2)], workers=2)
"""


def _processes() -> dict[int, tuple[int, int, str]]:
    """Every live process: pid -> (parent's pid, session id, command line)."""
    found = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            command = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError):  # ended meanwhile
            continue
        if fields[0] != "Z":
            found[int(stat.parent.name)] = (int(fields[1]), int(fields[3]), command)
    return found


def _session(session: int) -> dict[int, str]:
    """The live processes of ``session``: pid -> command line."""
    return {pid: command for pid, (_, sid, command) in _processes().items() if sid == session}


def _pool_workers(session: int | None = None) -> set[int]:
    """The pids of the pool workers in ``session`` (None: of this process): forks of a fork server."""
    processes = _processes()
    servers = {
        pid
        for pid, (parent, sid, command) in processes.items()
        if "multiprocessing.forkserver" in command and (sid == session if session else parent == os.getpid())
    }
    return {pid for pid, (parent, _, command) in processes.items() if parent in servers and "forkserver" in command}


def _kill(command: list[str], number: int, ready: Callable[[int], bool], folder: Path) -> tuple[int, str, dict]:
    """Run ``command`` in a session of its own, send it signal ``number`` once ``ready(its pid)``,
    and give the processes of its session GRACE_S to end: its exit code, its standard error and the
    processes left (killed then)."""
    errors = folder / "stderr.txt"
    with errors.open("wb") as stderr:  # a file: a process left behind would hold a pipe open
        process = subprocess.Popen(
            command, cwd=folder, env=ENV, stdout=subprocess.DEVNULL, stderr=stderr, start_new_session=True
        )
    try:
        deadline = time.monotonic() + 300
        while not ready(process.pid):
            assert process.poll() is None, f"it ended before it could be killed: {errors.read_text()[-2000:]}"
            assert time.monotonic() < deadline
            time.sleep(0.01)
        os.kill(process.pid, number)
        code = process.wait(timeout=120)
        end = time.monotonic() + GRACE_S
        while _session(process.pid) and time.monotonic() < end:
            time.sleep(0.1)
        return code, errors.read_text(), _session(process.pid)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        for pid in _session(process.pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def _stored(out: Path) -> Callable[[int], bool]:
    """Whether a campaign writing to ``out`` has stored a part."""
    return lambda pid: any((out / "runs").glob("part-*.parquet"))


def _pool_running(pid: int) -> bool:
    """A pool worker runs in the session that ``pid`` leads."""
    return bool(_pool_workers(session=pid))


def _check_exit(code: int, stderr: str, number: int) -> None:
    """SIGKILL ends a command where it is; SIGTERM stops it as Ctrl-C does."""
    if number == signal.SIGKILL:
        assert code == -signal.SIGKILL
    else:  # one line, no traceback, no stack dump
        assert code == 130, stderr[-3000:]
        assert len(stderr.strip().splitlines()) == 1, stderr[-3000:]
        assert "interrupted" in stderr


@pytest.mark.slow
@pytest.mark.parametrize("number", KILLS, ids=lambda number: signal.Signals(number).name)
def test_a_killed_reproduce_leaves_no_process_behind_and_runs_again_whole(tmp_path, number):
    results = tmp_path / "results"
    results.mkdir()
    out = results / "report"
    code, stderr, left = _kill([*MICROG, *REPRODUCE, "--out", str(out)], number, _pool_running, tmp_path)
    assert left == {}
    _check_exit(code, stderr, number)
    assert main([*REPRODUCE, "--duration", "0.2", "--out", str(out)]) == 0  # the last --duration counts
    report = json.loads((out / "report.json").read_text())
    assert {pad: sorted(rows) for pad, rows in report["metrics"].items()} == {
        "paper": ["1", "2", "3"],
        "calibrated": ["1", "2", "3"],
    }
    assert len(list(out.glob("fig*.png"))) == 5
    assert [p.name for p in results.iterdir()] == ["report"]  # no staging folder left


@pytest.mark.slow
def test_a_killed_compare_leaves_no_process_behind_and_runs_again_whole(tmp_path):
    """SIGKILL; SIGTERM takes reproduce's path (the pool's block left by KeyboardInterrupt)."""
    results = tmp_path / "results"
    results.mkdir()
    out = results / "comparison"
    code, stderr, left = _kill([*MICROG, *COMPARE, "--out", str(out)], signal.SIGKILL, _pool_running, tmp_path)
    assert left == {}
    _check_exit(code, stderr, signal.SIGKILL)
    assert main([*COMPARE, "--out", str(out)]) == 0
    cases = json.loads((out / "comparison.json").read_text())["cases"]
    assert sorted((case["controller"], case["seed"]) for case in cases) == [  # condition-2's seeds: 2000 on
        ("feedforward", 2000),
        ("feedforward", 2001),
        ("pid", 2000),
        ("pid", 2001),
    ]
    assert {case["scenario"] for case in cases} == {"condition-2"}
    assert [p.name for p in results.iterdir()] == ["comparison"]


@pytest.mark.slow
def test_a_killed_campaign_leaves_no_ray_process_behind_and_resumes_whole(tmp_path):
    """Ray's agents used to outlive a SIGKILLed driver by a minute. (SIGTERM, which printed Ray's
    stack dump, is the next test's.)"""
    spec, out = tmp_path / "c.yml", tmp_path / "out"
    spec.write_text(CAMPAIGN)
    command = [*MICROG, "campaign", str(spec), "--out", str(out), "--num-cpus", "1", "--quiet"]
    code, stderr, left = _kill(command, signal.SIGKILL, _stored(out), tmp_path)
    assert left == {}
    _check_exit(code, stderr, signal.SIGKILL)
    again = subprocess.run([*command, "--json"], cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-3000:]
    table = pq.read_table(out / "results.parquet")
    assert table.num_rows == 12
    assert len(set(table.column("spec_hash").to_pylist())) == 12
    assert set(table.column("status").to_pylist()) == {"ok"}


@pytest.mark.slow
def test_a_campaign_stopped_by_sigterm_runs_only_what_is_missing(tmp_path):
    """36 runs (6 of them fail: residual-sac-setpoint refuses 500 us). SIGTERM (Ctrl-C's path; it used to
    print Ray's stack dump) after the first stored batch: exit 130 in one line, no process of its
    session left, every finished row kept, no half-written file. The same command then runs only
    what is missing, and the table holds one row per run with every metric. A third start, on a
    local Ray instance of its own, tries the failed runs again and removes that instance's session
    folder (each campaign used to leave it in the system's temporary directory)."""
    path, out = tmp_path / "c.yml", tmp_path / "out"
    path.write_text(CAMPAIGN_36)
    command = [*MICROG, "campaign", str(path), "--out", str(out), "--num-cpus", "1", "--json", "--quiet"]
    code, stderr, left = _kill(command, signal.SIGTERM, _stored(out), tmp_path)
    assert left == {}
    _check_exit(code, stderr, signal.SIGTERM)
    before = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("part-*.parquet")}
    stored = ResultStore(out).statuses()
    assert 0 < len(stored) < 36
    assert not list((out / "runs").glob(".*"))  # no half-written file

    done = subprocess.run(command, cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    stored_ok = sum(status == "ok" for status in stored.values())
    assert summary["runs"] == 36
    assert summary["skipped"] == stored_ok
    assert summary["done"] + summary["failed"] == 36 - stored_ok
    assert summary["failed"] == 6
    for name, mtime in before.items():  # nothing stored was rewritten
        assert (out / "runs" / name).stat().st_mtime_ns == mtime
    table = pq.read_table(out / "results.parquet")
    assert table.num_rows == 36
    assert len(set(table.column("spec_hash").to_pylist())) == 36
    for name in [*RunMetrics.__dataclass_fields__, "qzs.guide_friction_n", "controller", "control_period_us"]:
        assert name in table.column_names
    rows = table.to_pylist()
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == 6
    assert all("1000 us" in r["error"] for r in failed)
    assert all(r["controller"] == "residual-sac-setpoint" and r["control_period_us"] == 500 for r in failed)
    ok = [r for r in rows if r["status"] == "ok"]
    assert all(np.isfinite(r["flexible_unit_excursion_free_fall_m"]) for r in ok)

    again = subprocess.run(
        [sys.executable, "-c", SESSIONS_SEEN, str(path), str(out)],
        cwd=tmp_path,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert again.returncode == 0, again.stderr
    result = json.loads(again.stdout.strip().splitlines()[-1])
    assert (result["skipped"], result["failed"]) == (30, 6)  # the failed runs are tried again
    assert len(result["sessions"]) == 1
    assert not Path(result["sessions"][0]).exists()


@pytest.mark.slow
@pytest.mark.parametrize("source", ["file", "stdin"])
def test_run_all_on_workers_from_a_script_they_cannot_import_says_what_to_do(tmp_path, source):
    """Without ``if __name__ == '__main__':`` each worker, importing the script, started a pool of
    its own and died with multiprocessing's bootstrapping traceback; run_all recorded every run as
    failed (BrokenProcessPool) and the script ended as if it had worked. A script read from
    standard input no worker can import."""
    script = tmp_path / "unguarded.py"
    script.write_text(UNGUARDED)
    command = [sys.executable, str(script) if source == "file" else "-"]
    result = subprocess.run(
        command, input=UNGUARDED, cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 1
    from microg_env.workers import UNGUARDED_SCRIPT, UNREADABLE_SCRIPT

    message = UNGUARDED_SCRIPT.format(script=script) if source == "file" else UNREADABLE_SCRIPT.format(script="<stdin>")
    assert result.stderr.strip().splitlines()[-1] == f"RuntimeError: {message}"
    assert "bootstrapping" not in result.stderr
    assert result.stderr.count("Traceback") == 1  # the script's own


@pytest.mark.slow
def test_leaving_a_pool_by_an_exception_drops_the_tasks_no_worker_took():
    """Ctrl-C in a pool's block used to wait for every task queued (a reproduction's every run)."""
    from microg_env.workers import process_pool

    futures = []

    def interrupted() -> None:
        with process_pool(2) as pool:
            futures.extend(pool.submit(time.sleep, 0.2) for _ in range(20))
            futures[0].result()
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        interrupted()
    # only those the workers took, or the pool had queued for them (6 here), ran; all 20 used to
    assert sum(future.cancelled() for future in futures) >= 10
    assert not _pool_workers()
