"""Identification from logs (microg_env.experiments.identify): hidden rigs recovered within the
intervals it states. The wider study, every parameter on two excitations, is
benchmarks/identifiability.py."""

import numpy as np
import pytest

from microg_env.experiments.identify import identify
from microg_env.rollout.replay import LogRecorder
from microg_env.rollout.runner import run
from microg_env.rollout.spec import RunSpec

#: What identify recovers of each parameter from 1 s of free fall (docs/model.md, Identification):
#: an error relative to the hidden value, or in metres.
TOLERANCES = {"servo.speed_loop_gain_hz": ("relative", 1e-3), "sensors.ruler_zero_offset_m": ("m", 1e-7)}


@pytest.mark.slow
@pytest.mark.parametrize("draw", range(3))
def test_identify_recovers_a_hidden_drive_and_ruler_zero_within_the_stated_tolerances(draw):
    """Three hidden rigs, each logged with its own seed, fitted from the paper's rig on 1 s of free
    fall (the replay's own draws, seed 0, differ from the log's, as a real rig's do)."""
    rng = np.random.default_rng(draw)
    hidden = {
        "servo.speed_loop_gain_hz": float(rng.uniform(70.0, 150.0)),  # the paper's rig: 100
        "sensors.ruler_zero_offset_m": float(rng.choice([-1.0, 1.0]) * rng.uniform(1e-6, 5e-6)),  # 0
    }
    recorder = LogRecorder()
    spec = RunSpec("condition-1", "pid", seed=100 + draw, duration_s=1.0, overrides=hidden, loads=((1.0, None),),
                   descent_height_m=0.01)  # fmt: skip
    run(spec, on_step=recorder)
    result = identify([recorder.log()], fit=list(hidden))
    for name, truth in hidden.items():
        kind, tolerance = TOLERANCES[name]
        unit = abs(truth) if kind == "relative" else 1.0
        assert abs(result.values[name] - truth) <= tolerance * unit, (name, truth, result.values[name])
    for channel in ("ruler_m", "encoder_m"):  # the identified rig replays the log to about its noise
        assert result.rms[channel] < 1.3 * result.noise[channel], channel  # measured 1.03-1.24
