"""The figures a user sees, rendered small and read back from the figure objects: units, legend
entries, events, line styles; the video's inset from its pixels."""

from dataclasses import replace

import numpy as np
import pytest

from microg_env.analysis.metrics import contacts
from microg_env.analysis.plots import ENVELOPE_BINS, envelope, run_events, run_figure
from microg_env.rollout.runner import run
from microg_env.rollout.spec import RunSpec
from microg_env.trajectory import CHANNELS


@pytest.fixture(scope="module")
def three_stage():
    """Condition 3 to its first lift-off: a weight placed in flight, a touchdown, a lift-off."""
    result = run(RunSpec("condition-3", "pid", duration_s=12.0))
    return result.trajectory, result.reference


def test_envelope_is_each_bins_min_mean_and_max():
    t = np.arange(10.0)
    y = np.array([0, 5, 1, 1, 2, 9, 3, 3, 3, 4], dtype=float)
    centres, low, mean, high = envelope(t, y, bins=3)  # edges 0, 3, 6, 9 (the last bin closed)
    np.testing.assert_allclose(centres, [1.5, 4.5, 7.5])
    np.testing.assert_allclose(low, [0, 1, 3])
    np.testing.assert_allclose(high, [5, 9, 4])
    np.testing.assert_allclose(mean, [2, 4, 13 / 4])
    few = np.array([0.0, 1.0])  # no more samples than bins: each is drawn at its own time
    np.testing.assert_array_equal(envelope(few, np.array([1.0, 2.0]))[0], few)
    assert len(envelope(np.arange(50.0), np.arange(50.0))[0]) == 50 < ENVELOPE_BINS


@pytest.mark.slow
def test_run_figure_marks_the_events_and_labels_its_units(three_stage):
    trajectory, reference = three_stage
    events = run_events(trajectory)
    found = contacts(trajectory)
    assert events["touchdown"] == [found[0].touchdown_s]
    assert events["lift-off"] == [found[0].liftoff_s]
    placed = trajectory.scenario.loads[1].height_m  # the second weight, placed in flight
    (when,) = events["weight placed"]
    k = int(np.searchsorted(trajectory.time_s, when))
    assert trajectory.foot_height_m[k] <= placed < trajectory.foot_height_m[k - 1]

    figure = run_figure(trajectory, reference, "condition 3", size=(4, 5))
    height, x, accel, force, zoom = figure.axes
    assert [ax.get_ylabel() for ax in (height, x, accel, force)] == [
        "foot height [mm]",
        "x [µm]",
        "lander accel. [mm/s$^2$]",
        "pad force [N]",
    ]
    assert [t.get_text() for t in height.get_legend().get_texts()] == [
        "rig",
        "ideal microgravity",
        "weight placed",
        "touchdown",
        "lift-off",
    ]
    for ax in (height, accel, force):  # the reference dashed
        styles = {line.get_label(): line.get_linestyle() for line in ax.get_lines()}
        assert styles["ideal microgravity"] == "--"
        marked = [line.get_xdata()[0] for line in ax.get_lines() if line.get_linestyle() in ("-.", ":")]
        assert sorted(marked) == pytest.approx(sorted([when, found[0].touchdown_s, found[0].liftoff_s]))
    assert [t.get_text() for t in x.get_legend().get_texts()] == ["min-max per bin", "mean per bin"]
    assert x.collections  # the ripple as a band, not a solid block of lines
    assert zoom.get_xlabel() == "time after the first touchdown [ms]"
    assert zoom.get_ylabel() == "x − x(touchdown) [µm]"
    assert "first 5 ms" in zoom.get_legend().get_texts()[0].get_text()
    (samples,) = zoom.get_lines()[:1]
    assert samples.get_xdata().max() == pytest.approx(20.0, abs=1.0)


def test_a_run_without_a_touchdown_says_so_in_the_zoom(three_stage):
    trajectory, reference = three_stage
    early = replace(trajectory, **{name: getattr(trajectory, name)[:500] for name in CHANNELS})  # 0.5 s
    zoom = run_figure(early, reference, "half a second", size=(4, 5)).axes[-1]
    assert [t.get_text() for t in zoom.texts] == ["no touchdown in this run: nothing to zoom on"]


@pytest.mark.slow
def test_figure_3_draws_both_pads_as_bands_that_do_not_hide_each_other():
    from microg_env.paper import figures, reproduction

    rep = reproduction.compute(duration_s=6.0, workers=1)
    figure = figures.render_figures(rep)["fig3_flexible_unit.png"]
    assert len(figure.axes) == 3
    for ax in figure.axes:
        assert ax.get_ylabel() == "x [µm]"
        assert len(ax.collections) == 2  # one min-max band per pad
        assert all(0 < band.get_alpha() < 1 for band in ax.collections)
    labels = [t.get_text() for t in figure.axes[0].get_legend().get_texts()]
    assert labels == [
        "Table 1 pad: mean per bin",
        "Table 1 pad: min-max per bin",
        "calibrated pad: mean per bin",
        "calibrated pad: min-max per bin",
    ]


@pytest.mark.slow
def test_figures_drawn_on_two_processes_are_those_drawn_on_one(tmp_path):
    from microg_env.paper import figures, reproduction

    rep = reproduction.compute(duration_s=0.5, workers=2)
    (tmp_path / "one").mkdir()
    (tmp_path / "two").mkdir()
    figures.save_figures(rep, tmp_path / "one", workers=1)
    figures.save_figures(rep, tmp_path / "two", workers=2)
    for name in figures.FIGURES:
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()


def test_video_frames_carry_an_inset_of_x_and_the_pad_force():
    """The inset plots the last INSET_S of x and the pad force, each in its colour, in a box at the
    frame's bottom right; what is older is left out."""
    from microg_env.analysis.video import FORCE_COLOUR, INSET_S, INSET_SIZE, X_COLOUR, LandingVideo

    video = LandingVideo("unused.gif", "test")
    for k in range(3001):
        t = k * 1e-3
        video.history.record({"time_s": t, "x_m": 1e-6 * np.sin(20 * t), "pad_force_n": max(0.0, 50 * np.sin(2 * t))})
    info = {"time_s": 3.0, "foot_height_m": 0.01, "x_m": 0.0, "pad_force_n": 0.0}
    frame = np.asarray(video._annotated(np.zeros((360, 480, 3), dtype=np.uint8), info).convert("RGB"))
    box = frame[360 - INSET_SIZE[1] - 6 :, 480 - INSET_SIZE[0] - 6 :]
    upper, lower = box[: INSET_SIZE[1] // 2], box[INSET_SIZE[1] // 2 :]
    assert (upper == X_COLOUR).all(axis=2).sum() > 150  # the x trace (and its label) across the box
    assert (lower == FORCE_COLOUR).all(axis=2).sum() > 150

    def force_rows(image):  # rows of the lower half, below its label, the force trace passes through
        lower = image[360 - 6 - INSET_SIZE[1] // 2 + 16 :, 480 - INSET_SIZE[0] - 6 :]
        return np.flatnonzero((lower == FORCE_COLOUR).all(axis=2).any(axis=1)).size

    assert force_rows(frame) > 20  # the hump of a landing
    assert (frame[70:200, :200] == 0).all()  # nothing drawn over the picture outside the caption and inset
    for k in range(3001, 9001):  # six more seconds: only the last INSET_S are kept in view
        t = k * 1e-3
        video.history.record({"time_s": t, "x_m": 0.0, "pad_force_n": 0.0})
    later = np.asarray(video._annotated(np.zeros((360, 480, 3), dtype=np.uint8), info | {"time_s": 9.0}).convert("RGB"))
    assert INSET_S < 6.0
    assert force_rows(later) == 1  # flat: the landing has left the window
