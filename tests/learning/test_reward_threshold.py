"""The residual ids' reward_threshold, measured (in a file of its own: the run is long and
parallel workers take whole files)."""

import gymnasium as gym
import numpy as np
import pytest

import microg_env  # noqa: F401  (registers the environments)


@pytest.mark.slow
@pytest.mark.parametrize(
    "env_id", ["MicroGravityLanding-Residual-v1", "MicroGravityLanding-Residual-v5", "MicroGravityLanding-Residual-v7"]
)
def test_the_reward_threshold_is_the_zero_residuals_measured_return(env_id):
    """Each base's reward_threshold is its zero residual's mean return over the id's own draws,
    seeds 1000-1099, rounded down (as ``training/returns_table.py`` measures it): measured here on
    a vector env of 100 rigs (rig i is the single env seeded 1000 + i, bit for bit)."""
    n = 100
    vector = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
    vector.reset(seed=1000)
    returns, running = np.zeros(n), np.ones(n, dtype=bool)
    while running.any():  # each rig's first episode (an ended rig resets and steps on, uncounted)
        _, reward, terminated, truncated, _ = vector.step(np.zeros((n, 1), dtype=np.float32))
        returns += np.where(running, reward, 0.0)
        running &= ~(terminated | truncated)
    vector.close()
    threshold = gym.spec(env_id).reward_threshold
    assert threshold <= returns.mean() < threshold + 1, returns.mean()
