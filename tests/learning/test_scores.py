"""The learning tasks' normalised score (microg_env/scores.py): what the environment reports at an
episode's end, single and vector alike, for the task as registered only, and its references as the
stored hundred returns give them (reference_returns.json)."""

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import microg_env  # noqa: F401  (registers the environments)
from microg_env.scores import REFERENCE_SEEDS, REFERENCES, normalized_score, scored_id

STORED = json.loads(Path(__file__).with_name("reference_returns.json").read_text())
GAINS = "MicroGravityLanding-GainScheduling-v1"


def _episode(env: gym.Env, seed: int, act) -> tuple[float, list[dict]]:
    """The return of one episode and every step's info."""
    observation, _ = env.reset(seed=seed)
    total, infos, done = 0.0, [], False
    while not done:
        observation, reward, terminated, truncated, info = env.step(act(observation))
        total += reward
        infos.append(info)
        done = terminated or truncated
    return total, infos


def test_the_references_are_the_stored_hundred_episodes_means():
    """0 is the zero action's (the paper's PID's on the command task) mean shortfall over seeds
    1000-1099, 1 the shipped policy's: a mean score over those seeds is the normalised mean return."""
    assert STORED["seeds"] == list(REFERENCE_SEEDS)
    for env_id, reference in REFERENCES.items():
        whole = np.array(STORED["whole_steps"][env_id], dtype=float)
        zero, one = np.array(STORED["returns"][env_id]), np.array(STORED["policy_returns"][env_id])
        assert reference.zero_shortfall == round(float(np.mean(whole - zero)), 6), env_id
        assert reference.one_shortfall == round(float(np.mean(whole - one)), 6), env_id
        assert reference.one_shortfall < reference.zero_shortfall, env_id  # the policy earns more


def test_the_score_is_reported_once_at_the_episodes_end_as_the_stored_return_gives_it():
    """The zero action on the gain-scheduling task, seed 1000: no score before the last step, and
    there the score of the whole-episode steps minus the return paid, which the stored return of
    that seed gives too."""
    env = gym.make(GAINS)
    total, infos = _episode(env, 1000, lambda _: np.zeros(3, dtype=np.float32))
    assert all("normalized_score" not in info for info in infos[:-1])
    whole = STORED["whole_steps"][GAINS][0]
    assert total == pytest.approx(STORED["returns"][GAINS][0], rel=1e-9)
    assert infos[-1]["normalized_score"] == pytest.approx(REFERENCES[GAINS].score(whole - total), rel=1e-12)
    assert infos[-1]["normalized_score"] == REFERENCES[GAINS].score(float(env.unwrapped.core.shortfall([0])[0]))


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_the_vector_env_reports_each_ended_rigs_score_as_the_single_env_does(mode):
    """Two rigs of the gain-scheduling task under the zero action: each rig's score, at the step
    its episode ends (masked by ``_normalized_score``; in ``final_info`` with same-step autoreset),
    is the single environment's of that seed, bit for bit."""
    seeds = [1000, 1001]
    single = [_episode(gym.make(GAINS), seed, lambda _: np.zeros(3, dtype=np.float32))[1][-1] for seed in seeds]
    vector = gym.make_vec(
        GAINS, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode=gym.vector.AutoresetMode(mode)
    )
    vector.reset(seed=seeds)
    scores, running = {}, np.ones(2, dtype=bool)
    while running.any():
        _, _, terminated, truncated, info = vector.step(np.zeros((2, 3), dtype=np.float32))
        ended = (terminated | truncated) & running
        where = info["final_info"] if mode == "SameStep" and ended.any() else info
        for i in np.flatnonzero(ended):
            assert where["_normalized_score"][i]
            scores[i] = where["normalized_score"][i]
        running &= ~ended
    assert [scores[0], scores[1]] == [info["normalized_score"] for info in single]


def test_an_episode_cut_by_a_step_limit_has_no_score_single_or_vector():
    """A step limit ends the episode before its schedule does: no score, from the single env under
    Gymnasium's TimeLimit as from the vector env's own max_episode_steps (it scored the cut episode
    as a whole one, 2.8 where the zero action scores about 0)."""
    _, infos = _episode(gym.make(GAINS, max_episode_steps=100), 1000, lambda _: np.zeros(3, dtype=np.float32))
    assert len(infos) == 100
    assert "normalized_score" not in infos[-1]
    vector = gym.make_vec(GAINS, num_envs=1, vectorization_mode="vector_entry_point", max_episode_steps=100)
    vector.reset(seed=1000)
    for _ in range(100):
        _, _, terminated, truncated, info = vector.step(np.zeros((1, 3), dtype=np.float32))
    assert truncated[0]
    assert not terminated[0]
    assert "normalized_score" not in info


def test_the_training_vec_env_passes_the_score_on_as_make_vec_env_does():
    """microg train's VecEnv gives SB3 the ended rig's score in its info, as make_vec_env does."""
    from stable_baselines3.common.env_util import make_vec_env

    from microg_env.learning.vec_env import BatchedVecEnv

    ours, theirs = BatchedVecEnv.make(1, **gym.spec(GAINS).kwargs), make_vec_env(GAINS, n_envs=1)
    scores = []
    for venv in (ours, theirs):
        venv.seed(1000)
        venv.reset()
        done = [False]
        while not done[0]:
            _, _, done, infos = venv.step(np.zeros((1, 3), dtype=np.float32))
        scores.append(infos[0]["normalized_score"])
    assert scores[0] == scores[1]


def test_the_hidden_entries_are_a_set_to_the_score():
    """The registered hidden entries listed in another order make the same task, and its score."""
    hidden = tuple(reversed(gym.spec(GAINS).kwargs["hidden_observations"]))
    assert scored_id(gym.make(GAINS, hidden_observations=hidden).unwrapped.settings) == GAINS


def test_a_task_made_otherwise_than_registered_has_no_score():
    """Another sensor set, another rig or the plain id is another task: its episodes end unscored."""
    assert scored_id(gym.make(GAINS).unwrapped.settings) == GAINS
    for env in (
        gym.make(GAINS, sensor_set="paper"),
        gym.make(GAINS, params={"pad.stiffness_n_per_m": 8000.0}),
        gym.make("MicroGravityLanding-v1"),
    ):
        assert scored_id(env.unwrapped.settings) is None
        assert env.unwrapped.core.score is None
    with pytest.raises(ValueError, match="no normalised score for 'MicroGravityLanding-v1'; scored: "):
        normalized_score("MicroGravityLanding-v1", 1.0)


def test_an_episode_that_ends_early_falls_short_by_every_step_it_did_not_run():
    """The command task driven at full speed down: the guide's end comes within a second, the
    steps not run count as earning 0, and the score is far below the paper's PID's (0)."""
    env = gym.make("MicroGravityLanding-Command-v1")
    total, infos = _episode(env, 1000, lambda _: np.ones(1, dtype=np.float32))
    assert infos[-1]["termination_reason"] is not None
    core = env.unwrapped.core
    assert len(infos) < core.shortfall([0])[0] + total  # fewer steps than a whole episode has
    whole = STORED["whole_steps"]["MicroGravityLanding-Command-v1"][0]
    assert core.shortfall([0])[0] == pytest.approx(whole - total, rel=1e-12)
    assert infos[-1]["normalized_score"] < -10
