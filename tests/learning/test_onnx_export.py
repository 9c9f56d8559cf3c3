"""The ONNX export computes the NumPy policy: onnxruntime's action equals ``MLPPolicy.predict`` to
1e-6 on 10^4 observations, for every shipped policy and for a network of each activation, mean clip
and squash or clip; the model carries how the policy is deployed."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from microg_env.controllers.policy import ACTIVATIONS, MLPPolicy
from microg_env.controllers.registry import check_policy_folder, deployed_hidden, folder_digest, policy_folder
from microg_env.interface import OBSERVATION_SCALES, shipped_policies
from microg_env.learning import onnx_export
from microg_env.learning.onnx_export import INPUT, policy_model, write_onnx

OBSERVATIONS = 10_000
TOLERANCE = 1e-6
DEPLOYMENT_PAGE = Path(__file__).resolve().parents[2] / "docs" / "deployment.md"


def _session(model) -> ort.InferenceSession:
    return ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])


def _observations(policy: MLPPolicy, rng: np.random.Generator) -> np.ndarray:
    """Float32 observations (as the controller shows the policy) over the policy's input range: half
    normal in its normalised units, half uniform to 1.5 times its clip, so a share is clipped (a
    policy without normalisation, whose clip is float32's largest: to 15)."""
    clip = min(policy.clip_obs, 10.0)
    scaled = np.concatenate(
        [
            rng.normal(0.0, 1.0, (OBSERVATIONS // 2, policy.obs_mean.size)),
            rng.uniform(-1.5, 1.5, (OBSERVATIONS // 2, policy.obs_mean.size)) * clip,
        ]
    )
    return (policy.obs_mean + np.sqrt(policy.obs_var + policy.epsilon) * scaled).astype(np.float32)


def _gap(policy: MLPPolicy, observations: np.ndarray, session: ort.InferenceSession) -> float:
    exported = session.run(None, {INPUT: observations.astype(np.float64)})[0]
    expected, _ = policy.predict(observations)
    assert exported.shape == expected.shape == (len(observations), policy.action_size)
    assert exported.dtype == np.float32
    return float(np.abs(exported - expected).max())


@pytest.mark.parametrize("name", shipped_policies())
def test_a_shipped_policys_onnx_file_acts_as_its_numpy_policy(name, tmp_path):
    path = write_onnx(name, tmp_path / f"{name}.onnx")
    _, policy = check_policy_folder(policy_folder(name))
    observations = _observations(policy, np.random.default_rng(0))
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert _gap(policy, observations, session) <= TOLERANCE
    actions, _ = policy.predict(observations)
    assert actions.std() > 0.1  # the observations move the action


@pytest.mark.parametrize("name", shipped_policies())
def test_a_shipped_policys_onnx_file_says_how_it_is_deployed(name, tmp_path):
    path = write_onnx(policy_folder(name), tmp_path / "policy.onnx")  # a folder's path works as a name does
    card, _ = check_policy_folder(policy_folder(name))
    env = card["env_kwargs"]
    meta = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_modelmeta().custom_metadata_map
    read = {key: json.loads(value) for key, value in meta.items()}
    assert read["policy"] == name
    assert read["policy_digest"] == folder_digest(policy_folder(name))
    assert read["env_id"] == card["env_id"]
    assert read["decision_period"] == env.get("decision_period", 1)  # a key left out: its default
    assert read["action_mode"] == env.get("action_mode", "speed")
    assert read["base_controller"] == env.get("base_controller", "pid")
    assert read["residual_limit_m"] == env.get("residual_limit_m", 1e-6)
    assert read["residual_highpass_hz"] == env.get("residual_highpass_hz", 0.0)
    assert read["residual_gate_m"] == env.get("residual_gate_m")
    assert read["gain_limit"] == env.get("gain_limit", 2.0)
    assert read["speed_limit_m_s"] == env.get("speed_limit_m_s", 1.25)
    assert read["hidden_observations"] == list(deployed_hidden(env))
    assert read["control_period_s"] == 0.001
    assert read["trained_rig"] == {}  # the shipped policies trained on the paper's rig
    assert dict(zip(read["observation"], read["observation_scales"], strict=True)) == OBSERVATION_SCALES


def _random_policy(activation: str, squash: bool, mean_clip: float, rng: np.random.Generator) -> MLPPolicy:
    """Three layers of random weights through a normalisation far from the identity (VecNormalize's
    with means of ±5, variances over eight decades, a clip of 4), the output layer scaled so that its
    value before the squash or clip has deviation 1.5 on normalised observations of deviation 2: actions spread
    over [-1, 1], a share saturated, and the hidden units on both sides of 0."""
    size, width = len(OBSERVATION_SCALES), 24
    weights = [rng.normal(0.0, 1.0, (width, size)), rng.normal(0.0, 1.0 / math.sqrt(width), (width, width))]
    biases = [rng.normal(0.0, 0.5, width), rng.normal(0.0, 0.5, width)]
    mean, var = rng.normal(0.0, 5.0, size), 10.0 ** rng.uniform(-4.0, 4.0, size)
    hidden = rng.normal(0.0, 2.0, (OBSERVATIONS, size))
    for weight, bias in zip(weights, biases, strict=True):
        hidden = ACTIVATIONS[activation](hidden @ weight.T + bias)
    head = rng.normal(0.0, 1.0, width)
    scale = 1.5 / (hidden @ head).std()
    offset = -(hidden @ head).mean() * scale
    return MLPPolicy(
        (*weights, scale * head[None, :]),
        (*biases, np.array([offset])),
        activation,
        squash,
        mean,
        var,
        4.0,
        1e-6,
        mean_clip,
    )


@pytest.mark.parametrize(
    ("squash", "mean_clip"), [(True, 0.0), (True, 0.7), (False, 0.0)], ids=["tanh", "mean clip", "clip"]
)
@pytest.mark.parametrize("activation", sorted(ACTIVATIONS))
def test_each_activation_exports_as_numpy_computes_it(activation, squash, mean_clip):
    rng = np.random.default_rng(1)
    policy = _random_policy(activation, squash, mean_clip, rng)
    observations = _observations(policy, rng)
    assert _gap(policy, observations, _session(policy_model(policy))) <= TOLERANCE
    actions = policy.predict(observations)[0]
    inside = np.abs(actions) < (math.tanh(mean_clip) if mean_clip else 0.99)
    assert 0.3 < inside.mean() < 0.95  # most actions between the limits, where an op's error shows


def test_every_numpy_activation_has_an_onnx_one():
    assert set(onnx_export.ACTIVATION_OPS) == set(ACTIVATIONS)


def test_the_composed_erf_is_within_a_few_units_in_the_last_place_of_math_erf():
    """onnxruntime has no float64 Erf: the export's own, on a dense grid over every piece and beyond."""
    g = onnx_export._Graph(onnx)
    out = onnx_export._erf(g, "u")
    graph = onnx.helper.make_graph(
        g.nodes,
        "erf",
        [onnx.helper.make_tensor_value_info("u", onnx.TensorProto.DOUBLE, [None])],
        [onnx.helper.make_tensor_value_info(out, onnx.TensorProto.DOUBLE, [None])],
        initializer=g.constants,
    )
    model = onnx.helper.make_model(
        graph, opset_imports=[onnx.helper.make_opsetid("", onnx_export.OPSET)], ir_version=onnx_export.IR_VERSION
    )
    u = np.concatenate([np.linspace(-8.0, 8.0, 400_001), np.linspace(-1e-6, 1e-6, 1001), [0.0, 6.0, -6.0, 1e300]])
    erf = _session(model).run(None, {"u": u})[0]
    assert np.abs(erf - np.vectorize(math.erf)(u)).max() <= 4e-15


def test_the_deployment_pages_examples_export_and_run_a_policy(tmp_path, monkeypatch, capsys):
    """docs/deployment.md's Python blocks, in turn, in an empty folder: the export, then onnxruntime."""
    monkeypatch.chdir(tmp_path)
    blocks = re.findall(r"```python\n(.*?)```", DEPLOYMENT_PAGE.read_text(encoding="utf-8"), flags=re.DOTALL)
    assert len(blocks) == 2
    for block in blocks:
        exec(compile(block, str(DEPLOYMENT_PAGE), "exec"), {})
    decision_period, *_ = capsys.readouterr().out.split()
    assert decision_period == "5"
