"""The residual ids' reward_threshold, measured (in a file of its own: the runs are long)."""

import gymnasium as gym
import numpy as np
import pytest

import microg_env  # noqa: F401  (registers the environments)
from microg_env.envs.period import x_reward
from microg_env.task import TaskSettings

#: The draws each threshold is the mean return over: seeds 1000-1099 (training/returns_table.py).
FIRST_SEED, RIGS = 1000, 100


def _zero_residual_runs(env_id: str) -> tuple[list[np.ndarray], float, int]:
    """x at every control period of each rig's first episode under the zero residual, on a vector env
    of 100 rigs (rig i is the single env seeded 1000 + i, bit for bit) acting every period; the
    guide's limit; the id's decision period. A zero residual is its base controller however often it
    acts, so the trajectories are the id's own."""
    period = gym.spec(env_id).kwargs["decision_period"]
    vector = gym.make_vec(env_id, num_envs=RIGS, vectorization_mode="vector_entry_point", decision_period=1)
    vector.reset(seed=FIRST_SEED)
    x, running = [[] for _ in range(RIGS)], np.ones(RIGS, dtype=bool)
    while running.any():  # an ended rig resets and steps on, uncounted
        _, _, terminated, truncated, info = vector.step(np.zeros((RIGS, 1), dtype=np.float32))
        for i in np.flatnonzero(running):
            x[i].append(info["x_m"][i])
        running &= ~(terminated | truncated)
    limit = vector.unwrapped.core.x_limit_m
    vector.close()
    return [np.array(each) for each in x], limit, period


def _return(x_m: np.ndarray, scale_m: float, limit_m: float, period: int) -> float:
    """The return the environment pays: each step the mean reward of the periods it ran (the last
    step may run fewer)."""
    paid = x_reward(x_m, scale_m, limit_m)
    return float(sum(paid[i : i + period].mean() for i in range(0, paid.size, period)))


@pytest.mark.slow
@pytest.mark.parametrize(
    "env_ids",
    [
        ("MicroGravityLanding-Residual-v1",),
        # one base (adaptive-dither) and one draw: one run scored at each id's reward scale
        ("MicroGravityLanding-Residual-v5", "MicroGravityLanding-Residual-v7"),
    ],
    ids=lambda env_ids: "+".join(env_id.rsplit("-", 1)[1] for env_id in env_ids),
)
def test_the_reward_threshold_is_the_zero_residuals_measured_return(env_ids):
    """Each base's reward_threshold is its zero residual's mean return over the id's own draws,
    seeds 1000-1099, rounded down (as ``training/returns_table.py`` measures it)."""
    specs = [gym.spec(env_id) for env_id in env_ids]
    for spec in specs[1:]:  # the same draws and base; a zero action passes either gate as 0
        differ = {k for k in {*spec.kwargs, *specs[0].kwargs} if spec.kwargs.get(k) != specs[0].kwargs.get(k)}
        assert differ <= {"reward_scale_m", "residual_gate_on"}, differ
    x, limit, period = _zero_residual_runs(env_ids[0])
    for spec in specs:
        scale = spec.kwargs.get("reward_scale_m", TaskSettings().reward_scale_m)
        mean = np.mean([_return(each, scale, limit, period) for each in x])
        assert spec.reward_threshold <= mean < spec.reward_threshold + 1, (spec.id, mean)


@pytest.mark.slow
def test_the_returns_scored_from_x_are_those_the_environment_pays():
    """The scoring above against the environment's own return, on v7 acting every 5 periods, seed
    1001 (its 4286 periods end on a step of one)."""
    env_id, seed = "MicroGravityLanding-Residual-v7", FIRST_SEED + 1
    period = gym.spec(env_id).kwargs["decision_period"]
    every_period, as_registered = gym.make(env_id, decision_period=1), gym.make(env_id)
    x, total = [], 0.0
    for env in (every_period, as_registered):
        env.reset(seed=seed)
    done = False
    while not done:
        _, _, terminated, truncated, info = every_period.step(np.zeros(1, dtype=np.float32))
        x.append(info["x_m"])
        done = terminated or truncated
    assert len(x) % period == 1
    done = False
    while not done:
        _, reward, terminated, truncated, _ = as_registered.step(np.zeros(1, dtype=np.float32))
        total += reward
        done = terminated or truncated
    limit = as_registered.unwrapped.core.x_limit_m
    scale = gym.spec(env_id).kwargs["reward_scale_m"]
    assert _return(np.array(x), scale, limit, period) == pytest.approx(total, rel=1e-12)
