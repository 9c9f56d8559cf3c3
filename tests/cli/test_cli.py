"""The microg command: output, JSON, and one-line errors with exit code 2 for any bad input."""

import ast
import io
import json
import math
import os
import pickle
import shutil
import subprocess
import sys
import time
from importlib.metadata import version
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

import microg_env
from microg_env import cli
from microg_env.cli import main
from microg_env.cli.common import DROP_OPTIONS, RUN_OPTIONS, naming
from microg_env.learning.settings import ENV_IDS
from microg_env.task import ACTING_KEYS
from microg_env.validate import FieldError

#: What `microg train` trains with no --env.
DEFAULT_ID = ENV_IDS[0]

REPO = Path(__file__).resolve().parents[2]


def _run(*args: str, cwd: Path = REPO, environment: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``python -m microg_env.cli ARGS`` in ``cwd``, with this checkout first on the path
    (``environment``: the whole environment, default this process's)."""
    environment = {**(os.environ if environment is None else environment), "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-m", "microg_env.cli", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=environment,
        check=False,
        timeout=120,
    )


def test_drop_json_default_is_the_paper_pad(capsys):
    assert main(["drop", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) == {
        "contact_time_s",
        "restitution",
        "max_deformation_m",
        "fitted_stiffness_n_per_m",
        "fitted_damping_n_s_per_m",
    }
    assert result["fitted_stiffness_n_per_m"]["analytic"] == 4666.0
    assert result["fitted_damping_n_s_per_m"]["analytic"] == 200.0
    assert result["max_deformation_m"]["analytic"] == pytest.approx(0.012438, rel=1e-4)  # 37.3 mm/s
    for entry in result.values():
        assert entry["rel_error"] == pytest.approx((entry["sim"] - entry["analytic"]) / entry["analytic"])
        assert abs(entry["rel_error"]) < 0.01


def test_drop_table_names_the_quantities(capsys):
    assert main(["drop", "--mass", "300", "--stiffness", "10000", "--damping", "500", "--velocity", "0.02"]) == 0
    out = capsys.readouterr().out
    for label in ("contact time", "restitution", "peak deformation", "fitted stiffness", "fitted damping"):
        assert label in out
    assert "M = 300 kg" in out


#: Each option with values it must refuse (beside the generic ones below), and the word the
#: one-line error must contain.
NUMERIC_OPTIONS = {
    ("drop", "--mass"): "mass",
    ("drop", "--stiffness"): "stiffness",
    ("drop", "--damping"): "damping",
    ("drop", "--velocity"): "velocity",
    ("run", "--height"): "height",
    ("run", "--duration"): "duration",
    ("run", "--control-period"): "control",
    ("run", "--physics-step"): "physics",
    ("run", "--stiffness"): "stiffness",
    ("run", "--damping"): "damping",
    ("run", "--seed"): "seed",
    ("run", "--load"): "load",
    ("reproduce", "--duration"): "duration",
    ("reproduce", "--seed"): "seed",
    ("export-mjcf /tmp/never-written.xml", "--load"): "load",
    ("export-mjcf /tmp/never-written.xml", "--physics-step"): "physics",
    ("export-mjcf /tmp/never-written.xml", "--stiffness"): "stiffness",
    ("export-mjcf /tmp/never-written.xml", "--damping"): "damping",
    ("train", "--timesteps"): "timesteps",
    ("train", "--n-envs"): "n-envs",
    ("train", "--eval-freq"): "eval-freq",
    ("train", "--eval-episodes"): "eval-episodes",
    ("train", "--checkpoint-freq"): "checkpoint-freq",
    ("train", "--seed"): "seed",
    ("compare", "--seeds"): "seeds",
    ("compare", "--first-seed"): "first-seed",
    ("compare", "--duration"): "duration",
    ("compare", "--workers"): "workers",
}
#: Negative, zero, NaN, infinities, huge, tiny, empty, wrong type.
BAD_NUMBERS = ["-1", "0", "nan", "inf", "-inf", "1e300", "1e-300", "", "ten", "0x10", "1,5"]
CHOICE_OPTIONS = {
    ("run", "--condition"): ["0", "4", "1.5", "one", ""],
    ("run", "--controller"): ["lqr", ""],
    ("run", "--pad"): ["foam", ""],
    ("drop", "--pad"): ["foam"],
    ("calibrate", "--source"): ["guess"],
    ("train", "--algo"): ["a2c", ""],
    ("compare", "--controllers"): ["lqr", "", "pid,,feedforward", "pid,/tmp"],
    ("compare", "--scenarios"): ["condition-4", "", "condition-1,"],
}
LONG = "x" * 230  # with a temporary name's prefix and suffix, over the usual 255-byte limit
PATH_OPTIONS = {
    ("run", "--plot"): [
        "",
        "myplot",
        "{dir}",
        "/nonexistent-folder/run.png",
        "/proc/run.png",
        f"{LONG}.png",
        "{readonly}.png",
        "{dangling}.png",
    ],
    ("reproduce", "--out"): [
        "",
        ".",
        "..",
        "nonexist/..",
        "{file}",
        "/nonexistent-folder/reproduction",
        LONG,
        "{dangling}",
        "{dirlink}",
        "new\nline",
    ],
    ("export-mjcf",): ["", "{dir}", "rig.txt", "rig.xml/", "/nonexistent-folder/rig.xml", "/dev/stdout", f"{LONG}.xml"],
    ("run", "--video"): [
        "",
        "video",
        "run.png",
        "{dir}",
        "/nonexistent-folder/run.gif",
        f"{LONG}.gif",
        "{dangling}/run.gif",
    ],
    ("compare", "--out"): ["", ".", "{file}", "{dir}/..", "/nonexistent-folder/comparison", LONG, "{dirlink}"],
    ("train", "--resume"): ["", "{file}", "/nonexistent-folder/run", "{dir}"],
    ("train", "--hyperparams"): ["", "{file}", "/nonexistent-folder/ppo.yml", "{dir}"],
    ("train", "--log-folder"): ["", "{file}", "{file}/logs", "/proc/logs"],
}


def _cases():
    for (command, option), word in NUMERIC_OPTIONS.items():
        for value in BAD_NUMBERS:
            if option in ("--seed", "--first-seed") and value == "0":
                continue  # seed 0 is a good seed
            yield [*command.split(), option, value], word
    for (command, option), values in CHOICE_OPTIONS.items():
        for value in values:
            yield [command, option, value], option.lstrip("-")
    for key, values in PATH_OPTIONS.items():
        for value in values:
            args = [key[0], value] if len(key) == 1 else [key[0], key[1], value]
            yield args, "FILE" if len(key) == 1 else key[1]
    commands = ("drop", "run", "view", "reproduce", "calibrate", "export-mjcf /tmp/never-written.xml", "train",
                "replay log.csv", "identify log.csv --out rig.toml")  # fmt: skip
    for command in (*commands, "compare"):
        yield [*command.split(), "--bogus"], "--bogus"
    yield ["--bogus"], "--bogus"
    yield ["fly"], "fly"
    # Values that are each fine alone but not together, or not for this rig.
    yield ["run", "--control-period", "150"], "control_period"
    yield ["run", "--height", "600"], "height"
    yield ["run", "--load", "0.05", "--load", "9"], "1e-2 g"
    yield ["run", "--load", "0.05@20"], "t = 0"
    yield ["run", "--load", "0.05", "--load", "1@100"], "descent height"
    yield ["run", "--stiffness", "1e10"], "stiffness"
    yield ["run", "--stiffness", "10"], "stiffness"
    yield ["run", "--damping", "5000"], "damping"
    # Named by the option, from the fields the errors carry (the cold review of the structured errors).
    yield ["run", "--damping", "5000"], "--damping"  # over-damped
    yield ["drop", "--damping", "1e5"], "--damping"
    yield ["run", "--stiffness", "250", "--randomize"], "--stiffness"  # a draw would bottom out
    yield ["run", "--controller", "residual-sac-setpoint", "--control-period", "500"], "--control-period"
    yield ["run", "--duration", "600", "--control-period", "100"], "steps"
    yield ["drop", "--mass", "700"], "--mass"
    yield ["drop", "--velocity", "0.32"], "thickness"
    yield ["drop", "--mass", "1e-6"], "--mass"
    yield ["drop", "--mass", "1e-200", "--stiffness", "1e-200"], "--stiffness"
    yield ["run", "--height", "5000"], "--height"
    yield ["run", "--load", "7"], "--load"
    yield ["run", "--load", "0.05@"], "--load"
    yield ["run", "--load", "0.05@25"], "--load"
    yield ["run", "--stiffness", "165", "--damping", "20"], "travel below touchdown"  # the screw's reach
    yield ["export-mjcf", "rig.xml", "--stiffness", "1e9"], "--stiffness"
    yield ["new\nline"], "new"
    yield ["run", "--randomize", "--no-imperfections"], "--randomize"
    yield ["run", "--randomize", "--ideal"], "--randomize"  # the option's name before 0.4.0
    yield ["run", "--controller", "residual-sac-setpoint", "--control-period", "500"], "trained at 1000 us"
    yield ["train", "--env", "CartPole-v1"], "--env"
    yield ["train", "--algo", "sac", "--resume", "{dir}"], "--resume"
    yield ["train", "--n-envs", "100000"], "--n-envs"
    yield ["train", "--eval-episodes", "5000"], "--eval-episodes"
    yield ["compare", "--seeds", "5000"], "--seeds"
    yield ["compare", "--workers", "1000"], "--workers"
    yield ["run", "--load", "1@100", "--video", "landing.gif"], "--load"  # named with --video too
    yield ["train", "-conf", "{hyperparams}", "--env", "CartPole-v1"], "error: --env"  # not blamed on the file
    yield ["run", "--controller", "{broken_policy}"], "policy card"
    yield ["compare", "--controllers", "{no_network}"], "policy.npz"
    # A rig file: refused before any work, named with --rig.
    for command in ("run", "view", "compare", "train", "export-mjcf rig.xml"):
        yield [*command.split(), "--rig", "{bad_rig}"], "--rig"
    yield ["run", "--rig", "nowhere.toml"], "--rig"
    yield ["export-onnx", "pid", "pid.onnx"], "POLICY"  # a baseline has no network
    yield ["export-onnx", "no-such-policy", "p.onnx"], "POLICY"
    yield ["export-onnx", "residual-sac-setpoint", "p.txt"], "FILE"
    # Rig logs: a bad log, output or parameter is named before any replay.
    yield ["run", "--log", "run.txt"], "--log"
    yield ["run", "--log", "run.csv", "--ideal"], "--log"
    yield ["train", "--resume", "{dir}", "--rig", "rig.toml"], "--resume"  # a run keeps the rig it began on
    yield ["replay", "nowhere.csv"], "LOG"
    yield ["replay", "{file}"], "LOG"
    yield ["replay", "{log}", "--rig", "{bad_rig}"], "--rig"
    yield ["replay", "{log}", "--window", "0"], "--window"
    yield ["identify", "{file}", "--out", "rig.toml"], "LOG"
    yield ["identify", "{log}", "--out", "rig.txt"], "--out"
    yield ["identify", "{log}", "--out", "rig.toml", "--fit", "pad.mass"], "--fit"
    yield ["identify", "{log}"], "--out"
    yield ["run", "--rig", "{dir}"], "--rig"


def _bad_input_folder(tmp_path: Path) -> Path:
    """A working folder holding what the cases' placeholders name, and files nothing may touch."""
    folder = tmp_path / "cwd"
    folder.mkdir()
    (folder / "existing-dir").mkdir()
    (folder / "existing-file").write_text("keep")
    (folder / "read-only.png").write_text("keep")
    (folder / "read-only.png").chmod(0o444)
    (folder / "dangling.png").symlink_to(folder / "nowhere.png")
    (folder / "dangling").symlink_to(folder / "nowhere")
    (folder / "dir-link").symlink_to(folder / "existing-dir")
    (folder / "broken-policy").mkdir()
    (folder / "broken-policy" / "policy.json").write_text("[1, 2]")
    (folder / "no-network").mkdir()
    (folder / "no-network" / "policy.json").write_text('{"env_kwargs": {}}')
    (folder / "ppo.yml").write_text((REPO / "microg_env" / "hyperparams" / "ppo.yml").read_text())
    (folder / "bad-rig.toml").write_text("lander.mass_kg = 3000.0\n")
    header = "# microg rig log 1\n# descent_height_m = 0.01\n# loads = [{ mass_kg = 1.0 }]\n"
    (folder / "log.csv").write_text(f"{header}time_s,command_m_s,ruler_m,encoder_m\n0,0,0,0.01\n0.001,0,0,0.01\n")
    return folder


PLACES = {
    "{dir}": "existing-dir",
    "{file}": "existing-file",
    "{readonly}": "read-only",
    "{broken_policy}": "broken-policy",
    "{no_network}": "no-network",
    "{hyperparams}": "ppo.yml",
    "{bad_rig}": "bad-rig.toml",
    "{log}": "log.csv",
    "{dangling}": "dangling",
    "{dirlink}": "dir-link",
}


def _placed(args: list[str]) -> list[str]:
    for key, name in PLACES.items():
        args = [a.replace(key, name) for a in args]
    return args


def _assert_refused(code: int, out: str, err: str, word: str, folder: Path, before: list[str]) -> None:
    """Exit 2, one line on stderr naming ``word``, nothing on stdout, nothing written or touched."""
    assert code == 2, err + out
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert word.lower() in lines[0].lower(), lines[0]
    assert "Traceback" not in err
    assert out == ""
    assert sorted(p.name for p in folder.iterdir()) == before
    assert sorted(p.name for p in (folder / "existing-dir").iterdir()) == []
    assert (folder / "existing-file").read_text() == "keep"
    assert (folder / "read-only.png").read_text() == "keep"
    assert not Path("/tmp/never-written.xml").exists()


CASES = list(_cases())


@pytest.mark.parametrize(("args", "word"), CASES, ids=lambda v: " ".join(v) if isinstance(v, list) else v)
def test_bad_input_is_one_line_naming_the_option_exit_2_and_writes_nothing(args, word, tmp_path, monkeypatch, capsys):
    """In process, as the console script calls :func:`main` (each command's subprocess is below)."""
    folder = _bad_input_folder(tmp_path)
    before = sorted(p.name for p in folder.iterdir())
    monkeypatch.chdir(folder)
    code = main(_placed(args))
    out, err = capsys.readouterr()
    _assert_refused(code, out, err, word, folder, before)


#: The first bad-input case of each command, and of no command: run as a user runs it, a process of
#: its own, so that a warning or a log line printed on the way would show as a second line.
SMOKE = list(
    {args[0] if not args[0].startswith("-") else "--": (args, word) for args, word in reversed(CASES)}.values()
)


@pytest.mark.parametrize(("args", "word"), SMOKE, ids=lambda v: " ".join(v) if isinstance(v, list) else v)
@pytest.mark.slow
def test_each_command_refuses_bad_input_in_a_process_of_its_own(args, word, tmp_path):
    folder = _bad_input_folder(tmp_path)
    before = sorted(p.name for p in folder.iterdir())
    start = time.perf_counter()
    result = _run(*_placed(args), cwd=folder)
    assert time.perf_counter() - start < 60
    _assert_refused(result.returncode, result.stdout, result.stderr, word, folder, before)


def test_export_mjcf_writes_a_model_that_compiles(tmp_path, capsys):
    out = tmp_path / "rig_resolved.xml"
    assert main(["export-mjcf", str(out), "--load", "0.05"]) == 0
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.body("load_0").mass[0] == 0.0  # in the model, held off the lander as at an episode's start
    assert model.geom("load_0").rgba[3] == pytest.approx(0.25)
    finest = tmp_path / "finest.xml"  # 10 us, the floor run accepts: 10 * 1e-6 fell below it
    assert main(["export-mjcf", str(finest), "--physics-step", "10"]) == 0
    assert mujoco.MjModel.from_xml_path(str(finest)).opt.timestep == pytest.approx(1e-5)
    finest.unlink()
    assert model.geom_solref[model.geom("pad").id, 0] < 0  # the computed pad contact is in it
    assert list(tmp_path.iterdir()) == [out]  # no temporary file left behind
    assert out.stat().st_mode & 0o777 == 0o666 & ~_umask()  # the usual permissions, not 0600


def test_the_exported_home_keyframe_holds_still_and_the_sliders_drive_the_support(tmp_path):
    """Loaded as mujoco.viewer's *Load key* does, the home keyframe is balanced (it was not: the
    servo saturated at -119 N m and the lander hit the guide stop within 0.5 s); the servo's
    control range spans the screw's stroke, and moving its position slider moves the support
    (the lander then drifts to a guide stop: x is unstable without the controller, Eq. 17)."""
    out = tmp_path / "rig.xml"
    assert main(["export-mjcf", str(out), "--load", "1.0"]) == 0  # a weight held off did fall to the stop
    model = mujoco.MjModel.from_xml_path(str(out))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    worst = 0.0
    for _ in range(10):  # 1 s with the controls at rest
        mujoco.mj_step(model, data, nstep=1000)
        worst = max(worst, float(np.abs(data.qacc).max()))
    assert worst < 1.0
    assert abs(data.qpos[1]) < 1e-5  # x stays within 10 µm of the QZS's balance
    gear = model.actuator("servo").gear[0]
    stroke = np.array(model.joint("screw").range) * gear
    for limits in model.actuator("servo").ctrlrange:  # one row per input: position and speed
        np.testing.assert_allclose(limits, stroke, rtol=1e-5)
    assert model.actuator("servo").ctrllimited.all()
    data.ctrl[0] += 0.01 * gear  # the position slider 10 mm up: the support follows
    mujoco.mj_step(model, data, nstep=2000)
    assert data.qpos[0] == pytest.approx(0.10, abs=1e-4)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_run_json_keys_and_signs(capsys, run_json_keys):
    assert main(["run", "--condition", "2", "--duration", "6", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert run_json_keys <= set(result)
    assert result["ideal_descent_accel_m_s2"] == [pytest.approx(-1.0 * 9.8009 / 621.0)]
    assert result["descent_accel_m_s2"][0] < 0  # down is negative
    assert result["collision_accel_m_s2"] > 0  # the pad pushes up


@pytest.mark.slow
def test_run_ending_on_the_pad_reports_null_with_reasons_not_wrong_numbers(capsys):
    """Condition 1 cut at 5.5 s ends during the first contact: it printed -11.6 % before."""
    assert main(["run", "--condition", "1", "--duration", "5.5", "--json"]) == 0
    short = json.loads(capsys.readouterr().out)
    assert main(["run", "--condition", "1", "--duration", "12", "--json"]) == 0
    full = json.loads(capsys.readouterr().out)
    assert short["compensation_error_pct"][0] == pytest.approx(full["compensation_error_pct"][0], abs=0.02)
    assert short["restitution"] is None
    assert short["unavailable"]["restitution"] == "the run ended before the first lift-off"
    assert main(["run", "--height", "0.5", "--duration", "5", "--json"]) == 0
    low = json.loads(capsys.readouterr().out)
    assert low["compensation_error_pct"] == [None]
    assert "descent fit needs" in low["unavailable"]["descent_accel_m_s2[0]"]


@pytest.mark.slow
def test_run_custom_loads_table_and_plot(tmp_path, capsys):
    plot = tmp_path / "run.png"
    args = ["run", "--load", "0.05", "--load", "1.0@30", "--height", "60", "--duration", "4", "--plot", str(plot)]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "custom" in out
    assert "stage 2" in out
    assert "compensation error" in out
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert list(tmp_path.iterdir()) == [plot]


def test_run_custom_pad_and_physics_step(capsys):
    assert main(["run", "--stiffness", "8000", "--damping", "250", "--physics-step", "50", "--duration", "2"]) == 0
    out = capsys.readouterr().out
    assert "K = 8000.0 N/m, D = 250.0 N s/m" in out
    assert "physics step 50 us" in out


def test_run_shows_its_progress_unless_quiet(capsys):
    """`microg run` was silent for the whole run; its bar counts the control steps to the end."""
    assert main(["run", "--duration", "2", "--json"]) == 0
    bar = capsys.readouterr().err
    assert "run:" in bar
    assert "100%" in bar
    assert "2.00k/2.00k" in bar
    assert main(["run", "--duration", "2", "--json", "--quiet"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("setting", [{"DISPLAY": ""}, {"DISPLAY": ":0", "MUJOCO_GL": "egl"}])
@pytest.mark.slow
def test_view_without_a_display_is_one_line_and_exit_2(setting):
    environment = {**os.environ, "WAYLAND_DISPLAY": ""} | setting
    result = _run("view", "--duration", "1", environment={key: value for key, value in environment.items() if value})
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1
    assert "microg view needs" in result.stderr
    assert result.stdout == ""


@pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb (Debian's xvfb; .ci/run installs it)")
@pytest.mark.slow
def test_view_shows_a_landing_in_the_viewer_under_xvfb_and_exits_cleanly(tmp_path):
    """microg view opens MuJoCo's passive viewer on a virtual screen, runs a second of condition 1
    paced to twice real time, closes the window and its thread, prints the metrics, exits 0."""
    display = f":{90 + os.getpid() % 100}"
    server = subprocess.Popen(
        ["Xvfb", display, "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        time.sleep(1.0)
        environment = {key: value for key, value in os.environ.items() if key != "MUJOCO_GL"} | {"DISPLAY": display}
        start = time.perf_counter()
        result = _run("view", "--duration", "1", "--speed", "2", cwd=tmp_path, environment=environment)
    finally:
        server.terminate()
        server.wait(timeout=10)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert result.stdout.startswith("condition 1: loads 0.49 kg")
    assert "1 s at 1000 us" in result.stdout
    assert time.perf_counter() - start > 0.5  # paced: 1 s of simulated time at twice real time
    assert list(tmp_path.iterdir()) == []


def test_a_closed_reader_ends_quietly(monkeypatch):
    """`microg drop | head -1`: the reader goes away; no BrokenPipeError traceback."""

    class ClosedPipe(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def fileno(self):
            return os.open(os.devnull, os.O_WRONLY)

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert cli.main(["drop"]) == 1


@pytest.mark.slow
def test_output_piped_into_a_closed_reader_leaves_no_traceback(tmp_path):
    errors = tmp_path / "stderr.txt"
    command = f"{sys.executable} -m microg_env.cli drop 2>{errors} | true"
    subprocess.run(command, shell=True, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, check=False)
    assert "Traceback" not in errors.read_text()


@pytest.mark.slow
def test_reproduce_writes_its_report_when_its_progress_reader_goes_away(tmp_path):
    """`microg reproduce 2>&1 | head`: the progress bar's reader closes; the report is still written."""
    out = tmp_path / "report"
    process = subprocess.Popen(
        [sys.executable, "-m", "microg_env.cli", "reproduce", "--duration", "0.2", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    process.stderr.close()
    process.wait(timeout=300)
    assert (out / "report.md").is_file()


@pytest.mark.slow
def test_a_results_file_in_the_way_of_the_default_report_folder(tmp_path):
    (tmp_path / "results").write_text("not a folder")
    result = _run("reproduce", "--duration", "1", "--quiet", cwd=tmp_path)
    assert result.returncode == 2
    assert "--out" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_run_video_renders_the_landing_with_x_and_the_pad_force(tmp_path, capsys):
    from PIL import Image

    out = tmp_path / "landing.gif"
    assert main(["run", "--condition", "2", "--duration", "0.5", "--video", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    with Image.open(out) as video:
        assert video.n_frames == 11  # 20 frames per simulated second, the reset's included
        assert video.size == (480, 360)
        top = np.asarray(video.convert("RGB"))[:60]
    assert (top == 0).all(axis=2).mean() > 0.5  # the caption band
    assert (top > 200).all(axis=2).sum() > 500  # with white text in it
    assert list(tmp_path.iterdir()) == [out]


@pytest.mark.slow
def test_run_randomize_draws_the_plant_from_the_seed(capsys):
    args = ["run", "--condition", "2", "--duration", "5.5", "--json", "--randomize"]
    values = []
    for seed in ("1", "1", "2"):
        assert main([*args, "--seed", seed]) == 0
        values.append(json.loads(capsys.readouterr().out)["reference_max_deformation_m"])
    assert values[0] == values[1] != values[2]
    assert main(["run", "--condition", "2", "--duration", "5.5", "--json", "--seed", "1"]) == 0
    nominal = json.loads(capsys.readouterr().out)["reference_max_deformation_m"]
    assert nominal != values[0]


@pytest.mark.slow
def test_compare_writes_its_folder_and_replaces_an_earlier_one(tmp_path, capsys):
    out = tmp_path / "comparison"
    args = ["compare", "--controllers", "pid", "--scenarios", "condition-3", "--seeds", "1", "--duration", "0.3"]
    for _ in range(2):
        assert main([*args, "--out", str(out), "--quiet"]) == 0
    assert "| pid |" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["comparison.json", "comparison.md", "metrics.png", "x_landing.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["comparison"]


@pytest.mark.slow
def test_train_and_resume_from_the_command_line(tmp_path, capsys):
    import yaml

    env_id = "MicroGravityLanding-Residual-v7"  # an untrained residual flies (its base's); a speed policy fails
    entry = yaml.safe_load((REPO / "microg_env" / "hyperparams" / "ppo.yml").read_text())[env_id]
    entry |= {"n_envs": 1, "n_steps": 64, "batch_size": 64, "n_epochs": 1, "policy_kwargs": "dict(net_arch=[8])"}
    conf = tmp_path / "ppo.yml"
    conf.write_text(yaml.safe_dump({env_id: entry}))
    common = ["--eval-freq", "64", "--eval-episodes", "1", "--checkpoint-freq", "64", "--quiet"]
    logs = tmp_path / "new" / "logs"  # missing parents are made
    args = ["train", "--env", env_id, "-conf", str(conf), "--timesteps", "64", "--log-folder", str(logs), *common]
    assert main(args) == 0
    run = logs / "ppo" / f"{env_id}_1"
    out = capsys.readouterr().out
    assert f"wrote {run}" in out
    assert "eval at 64 steps" in out
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--timesteps", "96", "--seed", "3"]) == 2  # a run keeps its settings
    assert "--seed cannot change" in capsys.readouterr().err
    assert main(["train", "--resume", str(run), "--timesteps", "128", *common]) == 0  # the same values may be given
    latest = json.loads((run / "checkpoints" / "latest.json").read_text())
    assert latest["timesteps"] == 128
    args_file = (run / "args.yml").read_text()
    assert "--timesteps 64" in args_file  # the command that started the run
    card = json.loads((run / "policy" / "policy.json").read_text())
    assert card["command"].startswith("microg train")


@pytest.mark.parametrize("module", ["rig", "learning"])
def test_ctrl_c_prints_one_line_and_exits_130(module, monkeypatch, capsys):
    """Ctrl-C in microg run or compare used to print a traceback."""
    import importlib

    def interrupted(args):
        raise KeyboardInterrupt

    name = {"rig": "_cmd_run", "learning": "_cmd_compare"}[module]
    monkeypatch.setattr(importlib.import_module(f"microg_env.cli.{module}"), name, interrupted)
    command = ["run"] if module == "rig" else ["compare", "--quiet"]
    assert main(command) == 130
    assert capsys.readouterr().err == "microg: interrupted\n"


@pytest.mark.parametrize("command", [["campaign", "/dev/zero"], ["train", "--hyperparams", "/dev/zero"]])
def test_a_device_given_as_a_settings_file_is_refused_not_read(command, capsys):
    """/dev/zero used to be read until memory ran out."""
    assert main(command) == 2
    err = capsys.readouterr().err
    assert "'/dev/zero' is not a regular file" in err
    assert err.count("\n") == 1


def test_a_yaml_alias_bomb_gives_a_short_error(tmp_path, capsys):
    """A 0.5 kB file whose aliases expand 9^8 times used to print a 226 MB error."""
    lines = ["a: &a [x, x, x, x, x, x, x, x, x]"]
    for i, name in enumerate("bcdefgh"):
        previous = "abcdefgh"[i]
        lines.append(
            f"{name}: &{name} [*{previous}, *{previous}, *{previous}, *{previous}, *{previous}, "
            f"*{previous}, *{previous}, *{previous}, *{previous}]"
        )
    lines.append(f"{DEFAULT_ID}: *h")
    path = tmp_path / "bomb.yml"
    path.write_text("\n".join(lines) + "\n")
    assert path.stat().st_size < 1000
    assert main(["train", "--hyperparams", str(path)]) == 2
    err = capsys.readouterr().err
    assert "--hyperparams" in err
    assert len(err) < 5000  # a few kB, not 226 MB


def test_errors_name_the_option_by_the_field_they_carry_not_by_words_in_the_message():
    """The CLI maps FieldError.fields to its options; a message that only mentions a word (here
    "stiffness") names no option, and a field error survives a process pool's pickling."""
    error = FieldError("K is too large", "PadParams.stiffness_n_per_m", "physics_step_s")
    assert str(naming(error, RUN_OPTIONS)) == "--stiffness: K is too large"
    assert str(naming(error, RUN_OPTIONS, every=True)) == "--stiffness, --physics-step: K is too large"
    plain = ValueError("the stiffness and the damping are wrong")
    assert naming(plain, RUN_OPTIONS) is plain
    assert str(naming(FieldError("too heavy", "mass", "velocity"), DROP_OPTIONS, every=True)) == (
        "--mass, --velocity: too heavy"
    )
    copied = pickle.loads(pickle.dumps(error))
    assert (type(copied), str(copied), copied.fields) == (FieldError, str(error), error.fields)


def test_a_bare_microg_prints_its_help(capsys):
    """A bare `microg` used to exit 2 with argparse's 'the following arguments are required'."""
    assert main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: microg")
    assert "reproduce" in out


@pytest.mark.slow
def test_version_is_the_installed_distributions():
    """`microg --version` prints the version pip installed, which is the package's __version__."""
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    result = subprocess.run(
        [sys.executable, "-m", "microg_env.cli", "--version"], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == f"microg {microg_env.__version__}"
    assert version("microg-env") == microg_env.__version__


# -- generated bad files: -conf entries, campaign files, policy folders, --resume folders ----------

#: Values no setting takes, put in place of one key's value at a time.
BAD_VALUES = ["0", "-1", "1.5", "'text'", "null", "[1, 2]", "{a: 1}", ".nan", "1e400", "true"]
CONF_KEYS = ["n_envs", "n_timesteps", "n_steps", "batch_size", "n_epochs", "learning_rate", "gamma", "clip_range"]
CONF_KEYS += ["policy_kwargs", "normalize", "env_kwargs", "policy"]
CAMPAIGN = {
    "name": "fuzz",
    "base": {"scenario": "condition-2", "controller": "pid", "duration_s": 0.3},
    "sweep": {"overrides.pad.stiffness_n_per_m": [8000.0]},
    "seeds": [0, 1],
    "batch_size": 4,
}


def _conf_cases():
    entry = yaml.safe_load((REPO / "microg_env" / "hyperparams" / "ppo.yml").read_text())[DEFAULT_ID]
    for key in CONF_KEYS:
        for value in BAD_VALUES:
            if (key, value) in {("normalize", "true"), ("normalize", "null"), ("env_kwargs", "null")}:
                continue  # good values: normalise; no keyword arguments
            if (key, value) in {("gamma", "0"), ("clip_range", "1.5"), ("learning_rate", "1.5")}:
                continue  # accepted by the algorithm (gamma 0: myopic; the others are numbers)
            yield f"conf {key}={value}", {**entry, key: yaml.safe_load(value)}
    env_cases = [("condition", 9), ("action_mode", "jump"), ("base_controller", "me"), ("decision_period", 0)]
    for key, value in [*env_cases, ("hidden_observations", ["heights"])]:
        yield f"conf env_kwargs.{key}={value}", {**entry, "env_kwargs": {**entry["env_kwargs"], key: value}}
    yield "conf net_arch=[-1]", {**entry, "policy_kwargs": "dict(net_arch=[-1])"}  # torch's RuntimeError


def _campaign_cases():
    for key in ("name", "base", "sweep", "seeds", "batch_size", "samples"):
        for value in BAD_VALUES:
            if (key, value) in {("seeds", "0"), ("seeds", "[1, 2]"), ("name", "'text'"), ("samples", "null")}:
                continue  # good values: seed 0; seeds 1 and 2; a name; no samples
            if (key, value) in {("sweep", "null"), ("base", "null")}:
                continue  # nothing swept; no base settings
            yield f"campaign {key}={value}", {**CAMPAIGN, key: yaml.safe_load(value)}
    for key in ("duration_s", "controller", "scenario", "physics_step_us", "randomize", "overrides"):
        for value in BAD_VALUES[:6]:
            if (key, value) in {("randomize", "true"), ("duration_s", "1.5"), ("duration_s", "null")}:
                continue  # good values: plants drawn; a 1.5 s run; the whole schedule
            yield f"campaign base.{key}={value}", {**CAMPAIGN, "base": {**CAMPAIGN["base"], key: yaml.safe_load(value)}}


@pytest.mark.parametrize(("case", "entry"), list(_conf_cases()), ids=lambda v: v if isinstance(v, str) else "")
def test_a_generated_bad_hyperparameter_entry_is_one_line_naming_the_file(case, entry, tmp_path, capsys):
    path = tmp_path / "ppo.yml"
    path.write_text(yaml.safe_dump({DEFAULT_ID: entry}))
    logs = tmp_path / "logs"
    start = time.perf_counter()
    code = main(["train", "-conf", str(path), "--timesteps", "64", "--log-folder", str(logs), "--quiet"])
    assert time.perf_counter() - start < 60
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert "ppo.yml" in err or "-conf" in err, err
    assert not logs.exists()  # no run folder, no run number used up


@pytest.mark.parametrize(("case", "data"), list(_campaign_cases()), ids=lambda v: v if isinstance(v, str) else "")
def test_a_generated_bad_campaign_file_is_one_line_naming_the_file(case, data, tmp_path, capsys):
    path, out = tmp_path / "c.yml", tmp_path / "out"
    path.write_text(yaml.safe_dump(data))
    start = time.perf_counter()
    code = main(["campaign", str(path), "--out", str(out), "--quiet"])
    assert time.perf_counter() - start < 60
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert "c.yml" in err, err
    assert not out.exists()


def _policy_cases():
    card = json.loads((REPO / "microg_env" / "policies" / "residual-sac-setpoint" / "policy.json").read_text())
    for key in (*ACTING_KEYS, "control_period_s"):
        for value in BAD_VALUES:
            if (key, value) in {
                ("decision_period", "1.5"),
                ("residual_limit_m", "1.5"),
                ("residual_highpass_hz", "1.5"),
                ("residual_highpass_hz", "0"),  # 0 Hz: no high-pass, a valid corner
                ("residual_gate_m", "0"),  # the pad's surface: a residual gated to the contact
                ("residual_gate_m", "null"),  # no gate
            }:
                continue
            bad = json.loads(json.dumps(card))
            bad["env_kwargs"][key] = yaml.safe_load(value)
            if isinstance(bad["env_kwargs"][key], float) and not math.isfinite(bad["env_kwargs"][key]):
                text = json.dumps(bad)  # NaN and Infinity: what Python's json writes for them
            else:
                text = json.dumps(bad, allow_nan=False)
            yield f"policy env_kwargs.{key}={value}", text
    for value in BAD_VALUES:
        if value != "{a: 1}":  # a mapping: deployment reads its acting keys, each defaulted when absent
            yield f"policy env_kwargs={value}", json.dumps({**card, "env_kwargs": yaml.safe_load(value)})


@pytest.mark.parametrize(("case", "text"), list(_policy_cases()), ids=lambda v: v if v.startswith("policy") else "")
def test_a_generated_bad_policy_card_is_one_line_naming_the_policy(case, text, tmp_path, capsys):
    import shutil

    folder = tmp_path / "policy"
    shutil.copytree(REPO / "microg_env" / "policies" / "residual-sac-setpoint", folder)
    (folder / "policy.json").write_text(text)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    start = time.perf_counter()
    code = main(["run", "--controller", str(folder), "--duration", "0.01", "--json"])
    assert time.perf_counter() - start < 60
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert code == 2, err + captured.out[:200]
    assert len(err.splitlines()) == 1, err
    assert "policy" in err.lower(), err
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    """A finished 128-step PPO run folder to damage (copies of it)."""
    tmp_path = tmp_path_factory.mktemp("run")
    entry = yaml.safe_load((REPO / "microg_env" / "hyperparams" / "ppo.yml").read_text())[DEFAULT_ID]
    entry |= {"n_envs": 2, "n_steps": 64, "batch_size": 64, "n_epochs": 1, "policy_kwargs": "dict(net_arch=[8])"}
    (tmp_path / "ppo.yml").write_text(yaml.safe_dump({DEFAULT_ID: entry}))
    args = ["train", "-conf", str(tmp_path / "ppo.yml"), "--timesteps", "128", "--eval-freq", "128"]
    args += ["--eval-episodes", "1", "--checkpoint-freq", "128", "--log-folder", str(tmp_path / "logs"), "--quiet"]
    assert main(args) == 0
    return next((tmp_path / "logs" / "ppo").iterdir())


@pytest.mark.slow
def test_train_without_sb3_contrib_names_the_extra_for_its_algorithms_resumed_runs_too(tmp_path, monkeypatch, capsys):
    """A CrossQ run resumed without --algo on a machine without sb3-contrib was a raw ImportError."""
    entry = yaml.safe_load((REPO / "microg_env" / "hyperparams" / "crossq.yml").read_text())[DEFAULT_ID]
    entry |= {"learning_starts": 32, "buffer_size": 1000, "batch_size": 16, "policy_kwargs": "dict(net_arch=[8])"}
    (tmp_path / "crossq.yml").write_text(yaml.safe_dump({DEFAULT_ID: entry}))
    args = ["train", "--algo", "crossq", "-conf", str(tmp_path / "crossq.yml"), "--timesteps", "64"]
    args += ["--eval-freq", "64", "--eval-episodes", "1", "--checkpoint-freq", "64", "--log-folder", str(tmp_path)]
    assert main([*args, "--quiet"]) == 0
    run = next((tmp_path / "crossq").iterdir())
    monkeypatch.setitem(sys.modules, "sb3_contrib", None)  # import sb3_contrib raises ImportError
    for command in (args, ["train", "--resume", str(run), "--timesteps", "128"]):
        capsys.readouterr()
        assert main([*command, "--quiet"]) == 2, command
        err = capsys.readouterr().err.strip()
        assert err.endswith("microg train needs the train extra: pip install 'microg-env[train]'"), err
    assert json.loads((run / "checkpoints" / "latest.json").read_text())["timesteps"] == 64  # nothing touched


def _resume_cases():
    for key in ("algo", "env_id", "seed", "timesteps", "n_envs", "eval_freq", "eval_episodes", "checkpoint_freq"):
        for value in BAD_VALUES:
            if (key, value) in {("seed", "0"), ("timesteps", "null"), ("n_envs", "null")}:
                continue  # good values: seed 0; the file's budget; the file's environments
            yield f"args.yml {key}={value}", "args.yml", key, value
    for key in ("timesteps", "best_cost", "base_cost", "finished", "sessions", "resume_commands", "model"):
        for value in BAD_VALUES:
            if (key, value) in {("best_cost", "0"), ("best_cost", "1.5"), ("best_cost", "null"), ("finished", "true")}:
                continue  # good values: costs, not evaluated yet, a finished run
            if (key, value) in {("base_cost", "0"), ("base_cost", "1.5"), ("base_cost", "null"), ("sessions", "0")}:
                continue
            yield f"latest.json {key}={value}", "checkpoints/latest.json", key, value


def _read_tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize(("case", "name", "key", "value"), list(_resume_cases()), ids=lambda v: v if " " in v else "")
@pytest.mark.slow
def test_a_generated_bad_run_folder_is_one_line_naming_its_file_and_is_left_unchanged(
    case, name, key, value, run_folder, tmp_path, capsys
):
    import shutil

    folder = tmp_path / "run"
    shutil.copytree(run_folder, folder)
    path = folder / name
    data = yaml.safe_load(path.read_text()) if name.endswith(".yml") else json.loads(path.read_text())
    if key not in data:
        pytest.skip(f"{name} has no {key}")
    data[key] = yaml.safe_load(value)
    path.write_text(yaml.safe_dump(data) if name.endswith(".yml") else json.dumps(data))
    before = _read_tree(folder)
    start = time.perf_counter()
    code = main(["train", "--resume", str(folder), "--timesteps", "256", "--quiet"])
    assert time.perf_counter() - start < 60
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert Path(name).name in err or "--resume" in err, err
    assert _read_tree(folder) == before


def test_a_misspelt_option_gets_the_closest_option_of_its_command(capsys):
    assert main(["run", "--seedd", "3"]) == 2
    assert capsys.readouterr().err.strip() == "microg: error: unrecognized arguments: --seedd 3; did you mean --seed?"
    assert main(["compare", "--refrence", "pid"]) == 2
    assert "did you mean --reference?" in capsys.readouterr().err
    assert main(["run", "stray"]) == 2
    assert "did you mean" not in capsys.readouterr().err  # a stray word is not an option


@pytest.mark.parametrize(
    ("argv", "cores", "started"),
    [
        (["reproduce", "--out", "x"], 2, True),  # a pool of one process per usable core by default
        (["reproduce", "--out", "x"], 1, False),  # one usable core (its affinity), however many the machine has
        (["reproduce", "--workers", "2"], 1, True),
        (["reproduce", "--workers=1"], 2, False),
        (["reproduce", "--workers", "1"], 2, False),
        (["reproduce", "--help"], 2, False),
        (["reproduce", "--hel"], 2, False),  # argparse's abbreviation of --help
        (["reproduce", "--workers", "01"], 2, False),  # one worker, as the command's parser reads it
        (["reproduce", "--work", "3"], 2, True),
        (["reproduce", "--seed", "1", "--workers"], 2, False),  # a bad option: the command's parser says so
        (["reproduce", "--workers", "many"], 2, False),
        (["run", "--condition", "2"], 2, False),
    ],
)
def test_a_pooled_command_starts_its_fork_server_before_it_imports_the_rest(monkeypatch, argv, cores, started):
    calls = []
    monkeypatch.setattr(cli, "start_fork_server", calls.append)
    monkeypatch.setattr(cli, "usable_cores", lambda: cores)
    cli._start_pool(argv)
    assert calls == ([cli.POOLED_COMMANDS["reproduce"]] if started else [])


def test_importing_the_package_imports_neither_mujoco_nor_the_environments():
    """The names are imported on first use: a command's fork server starts before the rest imports."""
    code = (
        "import sys, microg_env; "
        "print('microg_env.envs.landing' in sys.modules, 'mujoco' in sys.modules); "
        "from microg_env import RigParams, MicroGravityLandingEnv; "
        "print(RigParams.__name__, MicroGravityLandingEnv.__name__, 'microg_env.envs.landing' in sys.modules)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(REPO)},
        check=True, timeout=120,
    )  # fmt: skip
    assert done.stdout.split() == ["False", "False", "RigParams", "MicroGravityLandingEnv", "True"]
    for name in microg_env.__all__:
        assert getattr(microg_env, name) is not None
        assert name in dir(microg_env)
    assert microg_env.scenarios.Scenario is microg_env.Scenario  # its modules as attributes, as before
    with pytest.raises(AttributeError, match="no attribute 'Rigparams'"):
        microg_env.Rigparams  # noqa: B018
    # the names type checkers see (imported under TYPE_CHECKING) are the names it exports
    source = ast.parse((REPO / "microg_env" / "__init__.py").read_text(encoding="utf-8"))
    checked = next(
        node for node in source.body if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
    )
    typed = {alias.name: node.module for node in checked.body for alias in node.names}
    assert typed == microg_env._EXPORTS


#: What a usage error, a help or the version must not wait for: the physics, the learning and the plots.
HEAVY = ("mujoco", "numba", "scipy", "torch", "stable_baselines3", "ray", "matplotlib")
#: Usage errors that argparse or an option's type raises, as (argv, exit code).
LIGHT_ERRORS = [
    (["run", "--height", "-1"], 2),
    (["run", "--controller", "nope"], 2),
    (["run", "--pad", "nope"], 2),
    (["view", "--condition", "4"], 2),
    (["drop", "--mass", "-1"], 2),
    (["export-mjcf"], 2),
    (["reproduce", "--workers", "0"], 2),
    (["calibrate", "--source", "nope"], 2),
    (["train", "--algo", "nope"], 2),
    (["train", "--n-envs", "0"], 2),
    (["train", "--eval-episodes", "1001"], 2),
    (["compare", "--seeds", "0"], 2),
    (["compare", "--randomize", "nope"], 2),
    (["compare", "--workers", "0"], 2),
    (["compare", "--refrence", "pid"], 2),
    (["campaign"], 2),
    (["--seed", "1"], 2),
]


def test_usage_errors_help_and_version_import_none_of_the_physics():
    """Building the parser (a bare ``microg`` prints its help), ``--help`` (of ``microg`` and each
    command), ``--version`` and every usage error that argparse or an option's type raises import
    none of :data:`HEAVY`, in a process of their own; the first case that imports one is named."""
    commands = list(cli.build_parser()._subparsers._group_actions[0].choices)
    cases = [([], 0), (["--help"], 0), (["--version"], 0), *(([c, "--help"], 0) for c in commands), *LIGHT_ERRORS]
    code = (
        "import contextlib, io, json, sys\n"
        "from microg_env.cli import main\n"
        "for argv in json.loads(sys.argv[1]):\n"
        "    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):\n"
        "        try:\n"
        "            status = main(argv)\n"
        "        except SystemExit as stop:\n"
        "            status = stop.code\n"
        "    heavy = sorted({m.split('.')[0] for m in sys.modules} & set(json.loads(sys.argv[2])))\n"
        "    print(json.dumps([argv, status, heavy]))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, json.dumps([argv for argv, _ in cases]), json.dumps(HEAVY)],
        capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(REPO)}, check=True, timeout=120,
    )  # fmt: skip
    results = [json.loads(line) for line in done.stdout.splitlines()]
    assert [(argv, status) for argv, status, _ in results] == [(argv, status) for argv, status in cases]
    assert [(argv, heavy) for argv, _, heavy in results if heavy][:1] == []


def test_reproduce_without_matplotlib_stops_before_its_runs(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr("importlib.util.find_spec", lambda name, *args: None if name == "matplotlib" else object())
    monkeypatch.setattr(cli, "start_fork_server", lambda also: None)
    assert main(["reproduce", "--out", str(tmp_path / "report"), "--workers", "1", "--quiet"]) == 2
    assert "plots need matplotlib: pip install 'microg-env[report]'" in capsys.readouterr().err
    assert not (tmp_path / "report").exists()
