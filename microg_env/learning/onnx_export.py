"""Export an :class:`~microg_env.controllers.policy.MLPPolicy` to ONNX, for a real-time loop (the onnx extra).

The graph is the policy's ``predict``, in float64 from the observation to the action: the
normalisation, the layers, the mean clip and the tanh squash or the clip. It takes ``observation``,
float64 (N, observation size), and gives ``action``, float32 (N, action size), as ``predict`` does. It is built
from the NumPy arrays with ``onnx.helper`` (no torch). onnxruntime has no float64 kernel for Erf, Elu
or LeakyRelu, so those activations are composed of ops that have one; erf is a piecewise polynomial
(:func:`erf_pieces`) within a few units in the last place of ``math.erf``. The model's
``metadata_props`` hold how the policy is deployed (:func:`deployment_metadata`), each value a JSON
text; what the graph leaves to the caller (the decision period, the observation entries the
controller fills in, the residual's filter and gate, the base controller) is docs/deployment.md's.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from microg_env.controllers.policy import MLPPolicy
from microg_env.controllers.registry import (
    TASK_DEFAULTS,
    check_policy_folder,
    deployed_hidden,
    folder_digest,
    policy_folder,
)
from microg_env.files import atomic_path
from microg_env.interface import OBSERVATION_SCALES
from microg_env.task import ActingSettings
from microg_env.version import __version__

#: What a missing onnx or onnxruntime says.
ONNX_EXTRA = "exporting a policy to ONNX needs the onnx extra: pip install 'microg-env[onnx]'"
#: The opset and IR version of the exported model: not the newest, so that older runtimes load it.
OPSET, IR_VERSION = 17, 8
#: The model's input and output.
INPUT, OUTPUT = "observation", "action"
#: erf's pieces: |u| in [0, ERF_END) in pieces of ERF_PIECE, each a polynomial of ERF_DEGREE; erf(u) is
#: ±1 beyond (1 - erf(6) = 2e-17, below float64's resolution at 1).
ERF_PIECE, ERF_END, ERF_DEGREE = 0.5, 6.0, 12


def erf_pieces() -> np.ndarray:
    """The monomial coefficients of erf on each piece, (ERF_DEGREE + 1, pieces), lowest first, in the
    piece's own variable t in [-1, 1]: Chebyshev interpolants of ``math.erf``, within 2e-15 of it."""
    erf = np.vectorize(math.erf)
    pieces = round(ERF_END / ERF_PIECE)
    table = np.zeros((ERF_DEGREE + 1, pieces))
    for i in range(pieces):
        centre = (i + 0.5) * ERF_PIECE
        series = np.polynomial.chebyshev.chebinterpolate(lambda t, c=centre: erf(c + t * ERF_PIECE / 2), ERF_DEGREE)
        monomial = np.polynomial.chebyshev.cheb2poly(series)
        table[: monomial.size, i] = monomial
    return table


class _Graph:
    """An ONNX graph being built: each op's output and each constant named in order."""

    def __init__(self, onnx: Any) -> None:
        self.onnx = onnx
        self.nodes: list = []
        self.constants: list = []

    def constant(self, value: Any) -> str:
        name = f"c{len(self.constants)}"
        self.constants.append(self.onnx.numpy_helper.from_array(np.asarray(value, dtype=np.float64), name))
        return name

    def op(self, op_type: str, *inputs: str, **attributes: Any) -> str:
        name = f"t{len(self.nodes)}"
        self.nodes.append(self.onnx.helper.make_node(op_type, list(inputs), [name], **attributes))
        return name

    def clip(self, z: str, limit: float) -> str:
        return self.op("Clip", z, self.constant(-limit), self.constant(limit))


def _erf(g: _Graph, u: str) -> str:
    """erf(u), elementwise: the piece's polynomial (:func:`erf_pieces`) at |u|, with u's sign."""
    table = erf_pieces()
    last = table.shape[1] - 1
    size = g.op("Min", g.op("Abs", u), g.constant(ERF_END))
    piece = g.op("Min", g.op("Floor", g.op("Div", size, g.constant(ERF_PIECE))), g.constant(float(last)))
    centre = g.op("Mul", g.op("Add", piece, g.constant(0.5)), g.constant(ERF_PIECE))
    t = g.op("Div", g.op("Sub", size, centre), g.constant(ERF_PIECE / 2))
    index = g.op("Cast", piece, to=g.onnx.TensorProto.INT64)
    value = g.op("Gather", g.constant(table[-1]), index)
    for row in table[-2::-1]:  # Horner
        value = g.op("Add", g.op("Mul", value, t), g.op("Gather", g.constant(row), index))
    return g.op("Mul", g.op("Sign", u), value)


#: Each activation of :data:`~microg_env.controllers.policy.ACTIVATIONS` as ops with float64 kernels,
#: computed as the NumPy one is.
ACTIVATION_OPS: dict[str, Callable[[_Graph, str], str]] = {
    "tanh": lambda g, z: g.op("Tanh", z),
    "relu": lambda g, z: g.op("Relu", z),
    # relu(z) + (exp(min(z, 0)) - 1): z above 0, expm1(z) at or below (within 3e-16)
    "elu": lambda g, z: g.op(
        "Add", g.op("Relu", z), g.op("Sub", g.op("Exp", g.op("Min", z, g.constant(0.0))), g.constant(1.0))
    ),
    "leaky_relu": lambda g, z: g.op("Max", z, g.op("Mul", z, g.constant(0.01))),  # z >= 0.01 z exactly where z >= 0
    "gelu": lambda g, z: g.op(
        "Mul",
        g.op("Mul", g.constant(0.5), z),
        g.op("Add", g.constant(1.0), _erf(g, g.op("Div", z, g.constant(math.sqrt(2.0))))),
    ),
    "silu": lambda g, z: g.op(
        "Mul",
        g.op("Mul", z, g.constant(0.5)),
        g.op("Add", g.constant(1.0), g.op("Tanh", g.op("Mul", g.constant(0.5), z))),
    ),
}


def _onnx() -> Any:
    """The onnx package, or an ImportError naming the extra."""
    try:
        import onnx
    except ImportError as error:
        raise ImportError(ONNX_EXTRA) from error
    return onnx


def policy_model(policy: MLPPolicy, metadata: Mapping[str, str] | None = None) -> Any:
    """``policy`` as a checked ONNX model (``onnx.ModelProto``) that computes its ``predict``, with
    ``metadata`` as its ``metadata_props``."""
    onnx = _onnx()
    g = _Graph(onnx)
    std = np.sqrt(policy.obs_var + policy.epsilon)  # MLPPolicy's own deviation, computed as it computes it
    z = g.clip(g.op("Div", g.op("Sub", INPUT, g.constant(policy.obs_mean)), g.constant(std)), policy.clip_obs)
    for i, (weight, bias) in enumerate(zip(policy.weights, policy.biases, strict=True)):
        z = g.op("Gemm", z, g.constant(weight), g.constant(bias), transB=1)
        if i < len(policy.weights) - 1:
            z = ACTIVATION_OPS[policy.activation](g, z)
    if policy.mean_clip > 0.0:
        z = g.clip(z, policy.mean_clip)
    z = g.op("Tanh", z) if policy.squash else g.clip(z, 1.0)
    g.nodes.append(onnx.helper.make_node("Cast", [z], [OUTPUT], to=onnx.TensorProto.FLOAT))
    size = policy.obs_mean.shape[0]
    graph = onnx.helper.make_graph(
        g.nodes,
        "policy",
        [onnx.helper.make_tensor_value_info(INPUT, onnx.TensorProto.DOUBLE, ["batch", size])],
        [onnx.helper.make_tensor_value_info(OUTPUT, onnx.TensorProto.FLOAT, ["batch", policy.action_size])],
        initializer=g.constants,
    )
    model = onnx.helper.make_model(
        graph,
        opset_imports=[onnx.helper.make_opsetid("", OPSET)],
        ir_version=IR_VERSION,
        producer_name="microg_env",
        producer_version=__version__,
        doc_string="A microg policy's deterministic action; how it is deployed: metadata_props, docs/deployment.md",
    )
    onnx.helper.set_model_props(model, dict(metadata or {}))
    onnx.checker.check_model(model, full_check=True)
    return model


def deployment_metadata(folder: str | Path, card: Mapping[str, Any]) -> dict[str, str]:
    """How the policy of ``folder`` (with its ``card``) is deployed, each value a JSON text: its name and
    contents' digest, its environment id and algorithm (where the card has them), the control period, the
    rig it was trained on (its parameters unlike the paper's, ``microg train --rig``), its
    acting settings as deployed (hidden entries: :func:`~microg_env.controllers.registry.deployed_hidden`),
    the observation's entries and their scales (SI units per unit), and the exporting version."""
    env = card["env_kwargs"]
    acting = dataclasses.replace(ActingSettings.of(env), hidden_observations=deployed_hidden(env))
    fields = {
        "policy": Path(folder).name,
        "policy_digest": folder_digest(folder),
        **{key: card[key] for key in ("env_id", "algo") if key in card},
        "control_period_s": float(env.get("control_period_s", TASK_DEFAULTS["control_period_s"])),
        "trained_rig": dict(env.get("params") or {}),  # the rig's parameters unlike the paper's, by dotted path
        **dataclasses.asdict(acting),
        "observation": list(OBSERVATION_SCALES),
        "observation_scales": list(OBSERVATION_SCALES.values()),
        "microg_env_version": __version__,
    }
    return {key: json.dumps(value) for key, value in fields.items()}


def write_onnx(policy: str | Path, out_path: str | Path) -> Path:
    """Write the ONNX model of ``policy`` (a shipped policy's name or a policy folder) with its
    deployment metadata to ``out_path``, atomically; returns the path. A ValueError names a policy
    that does not load."""
    folder = policy_folder(str(policy))
    card, network = check_policy_folder(folder)
    model = policy_model(network, deployment_metadata(folder, card))
    with atomic_path(out_path) as temporary:
        temporary.write_bytes(model.SerializeToString())
    return Path(out_path)
