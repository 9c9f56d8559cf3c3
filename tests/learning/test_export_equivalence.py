"""The exported NumPy policy acts as stable-baselines3 does: for every actor option the learners
offer (algorithm x option, generated below), ``policy.npz`` gives ``model.predict(obs,
deterministic=True)`` to 1e-5 on 10^4 random observations, at actions spread over [-1, 1], through a
VecNormalize far from the identity; an option it cannot compute is refused, named."""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("sb3_contrib")
torch = pytest.importorskip("torch")
nn = torch.nn

from microg_env.controllers.policy import MLPPolicy  # noqa: E402
from microg_env.learning.export import export_policy  # noqa: E402
from microg_env.learning.hyperparams import ACTIVATION_NAMES, ALGORITHMS  # noqa: E402

ENV_ID = "MicroGravityLanding-v1"
OBSERVATIONS = 10_000
#: Each learner's own options of its actor: gSDE (SAC's family clips its mean to +-clip_mean with it,
#: PPO may squash its output), and CrossQ's batch renormalisation off.
OWN_OPTIONS = {
    "ppo": {"gSDE": {"use_sde": True}, "gSDE squashed": {"use_sde": True, "policy_kwargs": {"squash_output": True}}},
    "sac": {"gSDE": {"use_sde": True}, "gSDE, clip_mean 0.7": {"use_sde": True, "policy_kwargs": {"clip_mean": 0.7}}},
    "tqc": {"gSDE": {"use_sde": True}, "gSDE, no clip_mean": {"use_sde": True, "policy_kwargs": {"clip_mean": 0.0}}},
    "crossq": {"gSDE": {"use_sde": True}, "no batch_norm": {"policy_kwargs": {"batch_norm": False}}},
}
#: Options every learner's actor takes: each activation a policy_kwargs may name, other layer shapes.
SHARED_OPTIONS = {
    "default": {},
    **{
        f"nn.{name}": {"policy_kwargs": {"activation_fn": getattr(nn, name), "net_arch": [64, 64]}}
        for name in ACTIVATION_NAMES
    },
    "net_arch [32, 16, 8]": {"policy_kwargs": {"net_arch": [32, 16, 8]}},
    "no hidden layer": {"policy_kwargs": {"net_arch": []}},
}
CASES = [
    (algo, option, kwargs) for algo in ALGORITHMS for option, kwargs in (SHARED_OPTIONS | OWN_OPTIONS[algo]).items()
]


@pytest.fixture(scope="module")
def vec_env():
    from stable_baselines3.common.vec_env import DummyVecEnv

    env = DummyVecEnv([lambda: gym.make(ENV_ID)])
    yield env
    env.close()


def _normalization(vec_env, rng: np.random.Generator):
    """A VecNormalize far from the identity: means of +-5 scales, variances over eight decades, a
    clip that some observations reach, a non-default epsilon."""
    from stable_baselines3.common.vec_env import VecNormalize

    normalization = VecNormalize(vec_env, norm_reward=False, clip_obs=4.0, epsilon=1e-6)
    size = vec_env.observation_space.shape[0]
    normalization.obs_rms.mean = rng.normal(0.0, 5.0, size)
    normalization.obs_rms.var = 10.0 ** rng.uniform(-4.0, 4.0, size)
    return normalization


def _model(algo: str, kwargs: dict, env):
    from microg_env.learning.train import algorithm

    if algo != "ppo":
        kwargs = kwargs | {"buffer_size": 10}  # no replay memory to allocate: the model is never trained
    return algorithm(algo)("MlpPolicy", env, seed=0, device="cpu", **kwargs)


def _perturb(model, algo: str, observations: np.ndarray, rng: np.random.Generator) -> None:
    """Weights, and batch renormalisation statistics and gains, far from the learners' initial ones
    (whose actions sit near 0): the head's output centred and scaled to a deviation of 1.5 on
    ``observations`` (normalised), so the actions spread over [-1, 1], a good share squashed or clipped."""
    actor = model.policy if algo == "ppo" else model.actor
    with torch.no_grad():
        for module in actor.modules():
            if isinstance(module, nn.Linear):
                fan_in = module.weight.shape[1]
                module.weight.copy_(torch.as_tensor(rng.normal(0.0, 1.5 / np.sqrt(fan_in), module.weight.shape)))
                module.bias.copy_(torch.as_tensor(rng.normal(0.0, 0.3, module.bias.shape)))
            elif hasattr(module, "ra_var"):  # CrossQ's BatchRenorm1d
                size = module.num_features
                module.ra_mean.copy_(torch.as_tensor(rng.normal(0.0, 1.0, size)))
                module.ra_var.copy_(torch.as_tensor(rng.uniform(0.2, 3.0, size)))
                module.scale.copy_(torch.as_tensor(rng.uniform(0.5, 2.0, size)))
                module.bias.copy_(torch.as_tensor(rng.normal(0.0, 0.5, size)))
    head = actor.action_net if algo == "ppo" else actor.mu
    head = head if isinstance(head, nn.Linear) else head[0]  # gSDE's clip_mean follows the linear layer
    outputs = []
    hook = head.register_forward_hook(lambda module, inputs, output: outputs.append(output.detach().clone()))
    model.predict(observations[:1000], deterministic=True)
    hook.remove()
    z = torch.cat(outputs)
    with torch.no_grad():
        head.bias.sub_(z.mean(0))
        head.weight.mul_(1.5 / z.std())
        head.bias.mul_(1.5 / z.std())


@pytest.mark.slow
@pytest.mark.parametrize(("algo", "option", "kwargs"), CASES, ids=[f"{a}-{o}" for a, o, _ in CASES])
def test_the_exported_policy_acts_as_stable_baselines3_predicts(algo, option, kwargs, vec_env, tmp_path):
    rng = np.random.default_rng(sum(map(ord, algo + option)))
    normalization = _normalization(vec_env, rng)
    model = _model(algo, kwargs, normalization)
    stds = np.sqrt(normalization.obs_rms.var)
    observations = (normalization.obs_rms.mean + stds * rng.normal(0.0, 2.5, (OBSERVATIONS, stds.size))).astype(
        np.float32
    )
    normalized = normalization.normalize_obs(observations)
    _perturb(model, algo, normalized, rng)
    export_policy(model, normalization).save(tmp_path / "policy.npz")
    deployed = MLPPolicy.load(tmp_path / "policy.npz")  # what a policy folder runs, through its file

    theirs, _ = model.predict(normalized, deterministic=True)
    ours, _ = deployed.predict(observations)
    magnitude = np.abs(theirs)
    assert np.mean(magnitude > 0.5) > 0.3, "the actions must reach well beyond the linear middle"
    assert np.mean(magnitude < 0.9) > 0.1, "and some must stay inside, where a wrong squash or clip shows"
    np.testing.assert_allclose(ours, theirs, rtol=0.0, atol=1e-5)


@pytest.mark.slow  # torch and stable-baselines3 take seconds to import
@pytest.mark.parametrize(
    ("algo", "policy_kwargs", "named"),
    [
        ("ppo", {"activation_fn": nn.Sigmoid}, "Sigmoid"),
        ("sac", {"activation_fn": functools.partial(nn.LeakyReLU, 0.2)}, "LeakyReLU(negative_slope=0.2)"),
        ("ppo", {"activation_fn": functools.partial(nn.GELU, approximate="tanh")}, "GELU(approximate='tanh')"),
    ],
)
def test_an_actor_the_export_cannot_compute_is_refused_naming_what(algo, policy_kwargs, named, vec_env):
    model = _model(algo, {"policy_kwargs": policy_kwargs}, vec_env)
    with pytest.raises(ValueError, match=r"can export .*got .*" + named.replace("(", r"\(").replace(")", r"\)")):
        export_policy(model, None)
