"""Rig logs (microg_env.logs) and their replay (microg_env.rollout.replay): the schema round-trips
and refuses bad files in one line; a log the model wrote replays on the model to within its
sensors' noise; ``microg identify`` writes a rig file the other commands take."""

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from microg_env.cli import main
from microg_env.controllers import make_controller
from microg_env.experiments.identify import identify, reading_noise, touches_pad
from microg_env.logs import CSV_MAGIC, RigLog, read_log, write_log
from microg_env.params import RigParams, with_overrides
from microg_env.rigs import read_rig
from microg_env.rollout.episode import run_episode
from microg_env.rollout.replay import LogRecorder, replay
from microg_env.rollout.runner import run
from microg_env.rollout.spec import RunSpec
from microg_env.scenarios import LoadStep

#: A short test: 1 kg from 10 mm lands in about 1.1 s.
SHORT = {"loads": ((1.0, None),), "descent_height_m": 0.01}


def _logged(duration_s: float, seed: int = 0, overrides: dict | None = None, **spec) -> tuple[RigLog, object]:
    recorder = LogRecorder()
    result = run(
        RunSpec("condition-1", "pid", seed=seed, duration_s=duration_s, overrides=overrides or {}, **spec),
        on_step=recorder,
    )
    return recorder.log(), result


@pytest.fixture(scope="module")
def short_log() -> RigLog:
    """1.5 s of the PID landing 1 kg from 10 mm on the paper's rig, logged."""
    return _logged(1.5, **SHORT)[0]


def test_a_log_round_trips_through_csv_and_parquet(short_log, tmp_path):
    for suffix in (".csv", ".parquet"):
        path = tmp_path / f"log{suffix}"
        write_log(short_log, path)
        back = read_log(path)
        assert back.loads == short_log.loads
        assert back.descent_height_m == short_log.descent_height_m
        assert set(back.columns) == set(short_log.columns)
        for name, values in short_log.columns.items():
            np.testing.assert_array_equal(back.columns[name], values)
    assert (tmp_path / "log.csv").read_text().splitlines()[0] == CSV_MAGIC


def test_a_run_s_log_is_what_its_sensors_read_and_its_controller_sent():
    log, result = _logged(0.5)
    trajectory = result.trajectory
    assert log.rows == len(trajectory) - 1  # a row per step: the readings and the command they gave
    assert log.control_period_s == pytest.approx(1e-3)
    noise = reading_noise(RigParams())
    ruler_error = log.columns["ruler_m"] - trajectory.x_m[:-1]
    assert np.std(ruler_error) == pytest.approx(noise["ruler_m"], rel=0.2)  # 500 readings of 5 nm noise
    encoder_error = log.columns["encoder_m"] - trajectory.support_position_m[:-1]
    assert np.abs(encoder_error).max() <= 1.5e-9  # half a count of the 24-bit encoder (3 nm of travel)
    # The drive receives each command one period later (the control delay): the trajectory's command.
    np.testing.assert_allclose(log.columns["command_m_s"][:-1], trajectory.command_m_s[2:], rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda t: t.replace(CSV_MAGIC, "# some log"), "first line"),
        (lambda t: t.replace("ruler_m,", "ruler,"), "no column 'ruler_m'"),
        (lambda t: t.replace("# loads = ", "# lodes = "), "descent_height_m and loads"),
        (lambda t: t.replace("# descent_height_m = 0.01", "# descent_height_m = -1.0"), "descent_height_m"),
        (lambda t: t.replace("\n0.002,", "\n0.0025,", 1), "time_s must grow by one control period"),
        (lambda t: t.replace("\n0.002,", "\nnan,", 1), "time_s is not a finite number in row 3"),
        (lambda t: t.replace("pad_force_n", "pad_force_n,spare"), "6 columns"),
        (lambda t: "\n".join(t.splitlines()[:5]), "fewer than 2 rows"),  # a header and one row
    ],
)
def test_a_bad_log_is_refused_in_one_line_naming_it(short_log, tmp_path, edit, words):
    good = tmp_path / "good.csv"
    write_log(short_log, good)
    bad = tmp_path / "bad.csv"
    bad.write_text(edit(good.read_text()))
    with pytest.raises(ValueError, match="log") as caught:
        read_log(bad)
    message = str(caught.value)
    assert message.startswith(f"log '{bad}'")
    assert "\n" not in message
    assert words in message


def test_a_missing_or_misnamed_log_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"log '.*nowhere.csv' does not exist"):
        read_log(tmp_path / "nowhere.csv")
    with pytest.raises(ValueError, match=r"a log is a \.csv or \.parquet file"):
        read_log(tmp_path / "log.txt")


def test_a_log_replays_on_its_own_rig_to_within_its_sensors_noise(short_log):
    """The replay runs through the touchdown (about 1.1 s); a drive 10 % stiffer is seen."""
    assert touches_pad(short_log, RigParams())
    noise = reading_noise(RigParams())
    result = replay(short_log)
    assert result.ended is None
    assert result.encoder_m.size == short_log.rows
    rms = result.rms()
    assert rms["ruler_m"] < 1.2 * noise["ruler_m"]
    assert rms["encoder_m"] < 1.2 * noise["encoder_m"]
    stiffer = replay(short_log, with_overrides(RigParams(), {"servo.speed_loop_gain_hz": 110.0})).rms()
    assert stiffer["encoder_m"] > 100 * noise["encoder_m"]
    assert stiffer["ruler_m"] > 3 * noise["ruler_m"]


def test_identify_writes_a_rig_file_that_run_takes(short_log, tmp_path, capsys):
    log = tmp_path / "log.csv"
    write_log(RigLog({k: v[:300] for k, v in short_log.columns.items()}, 0.01, (LoadStep(1.0),)), log)
    start = tmp_path / "start.toml"
    start.write_text('description = "ours"\nlander.mass_kg = { value = 620.0, source = "scale" }\n')
    out = tmp_path / "identified.toml"
    argv = ["identify", str(log), "--rig", str(start), "--out", str(out), "--fit", "servo.speed_loop_gain_hz"]
    assert main([*argv, "--workers", "2", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["values"]["servo.speed_loop_gain_hz"] == pytest.approx(100.0, rel=1e-3)
    alone = identify([read_log(log)], read_rig(start).params, ["servo.speed_loop_gain_hz"])  # one process
    assert alone.values == report["values"]  # the pool's points are the same replays
    rig = read_rig(out)
    assert rig.description == "ours"
    assert rig.sources["lander.mass_kg"] == "scale"  # the start's own, kept
    assert rig.sources["servo.speed_loop_gain_hz"].startswith("microg identify from log.csv: +-")
    assert main(["run", "--rig", str(out), "--duration", "0.2", "--quiet", "--json"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["identified.toml", "log.csv", "start.toml"]


def test_replay_prints_the_residuals_beside_the_noise(short_log, tmp_path, capsys):
    log = tmp_path / "log.csv"
    write_log(short_log, log)
    assert main(["replay", str(log), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["rows_replayed"] == short_log.rows
    assert report["rms_m"]["ruler_m"] < 1.2 * report["reading_sd_m"]["ruler_m"]
    assert Path(log).exists()


def test_a_replay_refuses_windows_too_short_to_remove_the_start_state_and_commands_beyond_the_drive(short_log):
    """A 1-row window read 0 nm: every window's first row is the log's by construction."""
    with pytest.raises(ValueError, match=r"window_s 0\.002 holds 2 rows of the log; give at least 10"):
        replay(short_log, window_s=0.002)
    fast = RigLog(
        short_log.columns | {"command_m_s": short_log.columns["command_m_s"] * 0 + 2.0}, 0.01, short_log.loads
    )
    with pytest.raises(ValueError, match=r"command_m_s 2\.0 in row 1 is beyond the drive's 1\.25 m/s"):
        replay(fast)


def test_a_log_starts_where_its_episode_did():
    """With a perturbed start the log said the scenario's height, and replayed 117 um off."""
    recorder = LogRecorder()
    env = gym.make("microg_env:MicroGravityLanding-v1", condition=1, reset_noise_scale=0.005)
    run_episode(env, make_controller("pid", 1e-3), seed=3, duration_s=0.3, on_step=recorder)
    log = recorder.log()
    assert log.descent_height_m == env.unwrapped.core.episodes[0].height_m != 0.09
    assert replay(log).rms()["encoder_m"] < 1.2 * reading_noise(RigParams())["encoder_m"]


def test_a_log_records_the_speed_sent_at_the_environments_speed_limit():
    """On the command id an action of 1 is 0.1 m/s: the log read every action as 1.25 m/s."""
    recorder = LogRecorder()
    env = gym.make("MicroGravityLanding-Command-v1")
    _, info = env.reset(seed=1)
    recorder(env, info)
    actions = np.array([0.3, -0.2, 0.05], dtype=np.float32)
    for action in actions:
        _, _, _, _, info = env.step(action.reshape(1))
        recorder(env, info)
    np.testing.assert_allclose(recorder.log().columns["command_m_s"], actions * 0.1, rtol=1e-6)


def test_a_replay_window_starts_its_shifted_copies_from_the_replays_own_drive_state():
    """At each window the replay's two shifted copies take the first rig's state, the midpoint
    drive's last motor speed included: rigs driven apart and then copied step on bit for bit alike
    (before 0.22.0 the copies kept their own last speed, a different speed input each)."""
    from microg_env.envs.core import LandingCore
    from microg_env.rollout.replay import _copy_first_rig
    from microg_env.task import TaskSettings

    core = LandingCore(3, TaskSettings(condition=1), batched=True)
    every = np.arange(3)
    rngs = [np.random.default_rng(0) for _ in every]
    core.reset(every, rngs)
    for _ in range(20):  # each rig its own command: their drives part
        core.step(every, np.array([0.1, -0.2, 0.3]), rngs)
    assert len(set(core.motor_speed)) == 3
    _copy_first_rig(core)
    rngs = [np.random.default_rng(1) for _ in every]  # the same noise from here on
    x = []
    for _ in range(20):
        core.step(every, np.full(3, 0.05), rngs)
        x.append(core.info(every, np.zeros(3, dtype=np.int64))["x_m"])
    x = np.array(x)
    np.testing.assert_array_equal(x[:, 1], x[:, 0])
    np.testing.assert_array_equal(x[:, 2], x[:, 0])
