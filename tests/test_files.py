"""Writing results: atomic files, atomic folder swaps that survive a hard kill, output checks."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from microg_env.files import atomic_path, check_output_file, recover_folder, replace_folder, write_text
from microg_env.paper import report

REPO = Path(__file__).resolve().parents[1]


def _fill(text: str):
    def fill(staging: Path) -> None:
        (staging / "report.md").write_text(text)

    return fill


def test_write_text_is_atomic_and_has_the_usual_permissions(tmp_path):
    target = tmp_path / "out.xml"
    write_text(target, "<mujoco/>")
    assert target.read_text() == "<mujoco/>"
    mask = os.umask(0)
    os.umask(mask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~mask

    def interrupted() -> None:
        with atomic_path(target) as temporary:
            temporary.write_text("half")
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        interrupted()
    assert target.read_text() == "<mujoco/>"
    assert [p.name for p in tmp_path.iterdir()] == ["out.xml"]


@pytest.mark.parametrize(
    ("name", "word"),
    [("", "empty"), ("plot", "end in"), ("missing/plot.png", "does not exist"), ("folder.png", "not a regular file")],
)
def test_output_files_are_checked_before_any_work(tmp_path, name, word):
    (tmp_path / "folder.png").mkdir()
    with pytest.raises(ValueError, match=word):
        check_output_file(str(tmp_path / name) if name else "", "--plot", (".png",))


def test_special_files_are_never_replaced():
    """`export-mjcf /dev/stdout` renamed a file over the /dev/stdout link as root."""
    with pytest.raises(ValueError, match="not a regular file"):
        check_output_file("/dev/stdout", "FILE", ("",))


def test_replace_folder_keeps_the_old_folder_until_the_new_one_is_complete(tmp_path):
    out = tmp_path / "report"
    replace_folder(out, _fill("first"))

    def broken(staging: Path) -> None:
        (staging / "report.md").write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        replace_folder(out, broken)
    assert (out / "report.md").read_text() == "first"
    assert [p.name for p in tmp_path.iterdir()] == ["report"]
    replace_folder(out, _fill("second"))
    assert (out / "report.md").read_text() == "second"
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]


def test_stale_staging_from_a_killed_run_is_removed_on_the_next_run(tmp_path):
    out = tmp_path / "report"
    replace_folder(out, _fill("first"))
    stale = tmp_path / ".report.staging-abc123"
    stale.mkdir()
    (stale / "report.md").write_text("killed while writing")
    recover_folder(out)
    assert [p.name for p in tmp_path.iterdir()] == ["report"]
    assert (out / "report.md").read_text() == "first"


def test_a_kill_between_the_two_renames_is_recovered(tmp_path):
    out = tmp_path / "report"
    # Killed after the old report was moved aside and before the new one was moved in.
    retired = tmp_path / ".report.old-xyz"
    (retired / "report").mkdir(parents=True)
    (retired / "report" / "report.md").write_text("old")
    complete = tmp_path / ".report.staging-new"
    complete.mkdir()
    (complete / "report.md").write_text("new")
    (complete / ".complete").touch()
    recover_folder(out)
    assert (out / "report.md").read_text() == "new"  # the complete new report wins
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]
    # With no complete staging folder, the previous report is put back.
    out2 = tmp_path / "other"
    (tmp_path / ".other.old-q" / "other").mkdir(parents=True)
    (tmp_path / ".other.old-q" / "other" / "report.md").write_text("previous")
    recover_folder(out2)
    assert (out2 / "report.md").read_text() == "previous"


@pytest.mark.slow
def test_a_hard_kill_while_the_report_is_written_leaves_nothing_behind_after_the_next_run(tmp_path):
    out = tmp_path / "report"
    script = textwrap.dedent(
        f"""
        import time
        from pathlib import Path
        from microg_env.files import replace_folder

        def slow(staging):
            (staging / "report.md").write_text("partial")
            print("writing", flush=True)
            time.sleep(60)

        replace_folder(Path({str(out)!r}), slow)
        """
    )
    process = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)}
    )
    assert process.stdout.readline().strip() == "writing"
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert any(p.name.startswith(".report.staging-") for p in tmp_path.iterdir())
    report.check_output(out)  # what the next `microg reproduce --out` does first
    assert list(tmp_path.iterdir()) == []
    replace_folder(out, _fill("next"))
    assert [p.name for p in tmp_path.iterdir()] == ["report"]


def test_read_only_files_are_not_replaced(tmp_path):
    target = tmp_path / "out.xml"
    target.write_text("keep")
    target.chmod(0o444)
    with pytest.raises(ValueError, match="read-only"):
        check_output_file(str(target), "FILE", (".xml",))


def test_a_kill_after_the_swap_but_before_the_marker_was_removed(tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "report.md").write_text("new")
    (out / ".complete").touch()
    report.check_output(out)  # it used to refuse: "holds files that are not a report (.complete)"
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]


def test_a_folder_lock_refuses_a_second_writer_and_goes_with_the_first(tmp_path):
    from microg_env.files import folder_lock

    folder = tmp_path / "run"
    with (
        folder_lock(folder, "run folder"),
        pytest.raises(ValueError, match=r"run folder '.*run' is being written by another process"),
        folder_lock(folder, "run folder"),
    ):
        pass
    with folder_lock(folder, "run folder"):  # released: the next writer may go on
        pass
