"""The learning ids' reward_threshold: the mean return of the id's reference over its own draws, seeds
1000-1099, rounded down (as ``training/returns_table.py`` measures it). The reference is the zero
action (the base controller as tuned) on a residual or gain-scheduling id, the paper's PID on the
command id. The hundred returns are stored in ``reference_returns.json``; ``python
tests/learning/test_reward_threshold.py`` measures them again (a minute) and rewrites it. A test
re-runs three of them: the first seed's, the lowest and the highest. The same file holds each
seed's whole-episode steps and the score reference's returns (microg_env/scores.py), re-run alike."""

import json
import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import microg_env  # noqa: F401  (registers the environments)
from microg_env.controllers.registry import check_policy_folder, make_controller, shipped_policy_folder
from microg_env.envs.period import x_reward
from microg_env.interface import MAX_SPEED_M_S
from microg_env.scores import REFERENCES
from microg_env.task import ActingSettings, TaskSettings

#: The draws each threshold is the mean return over: seeds 1000-1099 (training/returns_table.py).
FIRST_SEED, RIGS = 1000, 100
#: Ids whose reference runs the same: one controller and one draw, scored at each id's reward scale.
GROUPS = (
    ("MicroGravityLanding-Residual-v6", "MicroGravityLanding-Residual-v7"),
    ("MicroGravityLanding-GainScheduling-v1",),
    ("MicroGravityLanding-Command-v1",),
)
RETURNS = Path(__file__).with_name("reference_returns.json")


def _reference_runs(env_id: str, seeds: list[int]) -> tuple[list[np.ndarray], float, int, np.ndarray]:
    """x at every control period of each seed's first episode under the id's reference, on a vector
    env of one rig a seed (the single env of that seed, bit for bit) acting every period; the
    guide's limit; the id's decision period; each episode's control periods. A zero residual or
    gains action is its base controller however often it acts; the command id's PID runs at the
    drive's own action unit, every entry shown (neither changes the draws or the physics): so the
    trajectories are the id's own."""
    registered = ActingSettings.of(gym.spec(env_id).kwargs)
    period, speed = registered.decision_period, registered.action_mode == "speed"
    acting = {"speed_limit_m_s": MAX_SPEED_M_S, "hidden_observations": ()} if speed else {"decision_period": 1}
    rigs = len(seeds)
    vector = gym.make_vec(env_id, num_envs=rigs, vectorization_mode="vector_entry_point", **acting)
    observation, _ = vector.reset(seed=seeds)
    periods = vector.unwrapped.core.max_steps.copy()
    pid = make_controller("pid", vector.unwrapped.settings.control_period_s) if speed else None
    x, running = [[] for _ in range(rigs)], np.ones(rigs, dtype=bool)
    while running.any():  # an ended rig resets and steps on, uncounted
        action = pid(observation) if speed else np.zeros(vector.action_space.shape, dtype=np.float32)
        observation, _, terminated, truncated, info = vector.step(action)
        for i in np.flatnonzero(running):
            x[i].append(info["x_m"][i])
        running &= ~(terminated | truncated)
    limit = vector.unwrapped.core.x_limit_m
    vector.close()
    return [np.array(each) for each in x], limit, period, periods


def _return(x_m: np.ndarray, scale_m: float, limit_m: float, period: int) -> float:
    """The return the environment pays: each step the mean reward of the periods it ran (the last
    step may run fewer)."""
    paid = x_reward(x_m, scale_m, limit_m)
    return float(sum(paid[i : i + period].mean() for i in range(0, paid.size, period)))


def _returns(group: tuple[str, ...], seeds: list[int]) -> tuple[dict[str, list[float]], list[int]]:
    """Each id's reference's return on each of ``seeds``, from one run of the group's first id, and
    each seed's whole-episode steps (its control periods over the decision period, rounded up)."""
    x, limit, period, periods = _reference_runs(group[0], seeds)
    out = {}
    for env_id in group:
        scale = gym.spec(env_id).kwargs.get("reward_scale_m", TaskSettings().reward_scale_m)
        out[env_id] = [_return(each, scale, limit, period) for each in x]
    return out, [int(-(-each // period)) for each in periods]


def _policy_returns(env_id: str, seeds: list[int]) -> tuple[list[float], list[int]]:
    """The return of the task's score reference (:data:`microg_env.scores.REFERENCES`' ``one``, a
    shipped policy) on each seed's first episode, on a vector env of one rig a seed, and each
    episode's whole-episode steps as the environment counts them."""
    _, policy = check_policy_folder(shipped_policy_folder(REFERENCES[env_id].one))
    vector = gym.make_vec(env_id, num_envs=len(seeds), vectorization_mode="vector_entry_point")
    observation, _ = vector.reset(seed=seeds)
    core = vector.unwrapped.core
    whole = [int(each) for each in core.shortfall(np.arange(len(seeds)))]  # no step taken: the whole
    returns, running = np.zeros(len(seeds)), np.ones(len(seeds), dtype=bool)
    while running.any():  # an ended rig resets and steps on, uncounted
        observation, reward, terminated, truncated, _ = vector.step(policy.predict(observation)[0])
        returns[running] += reward[running]
        running &= ~(terminated | truncated)
    vector.close()
    return returns.tolist(), whole


def _stored(entry: str = "returns") -> dict[str, list]:
    """The stored ``entry``: "returns" (each id's reference's), "whole_steps" or "policy_returns"
    (the score reference's), each id's list over the hundred seeds."""
    stored = json.loads(RETURNS.read_text())
    assert stored["seeds"] == [FIRST_SEED, FIRST_SEED + RIGS - 1]
    return stored[entry]


def test_each_group_runs_one_base_on_one_draw():
    """The ids of a group differ in their reward scale alone."""
    for group in GROUPS:
        first = gym.spec(group[0]).kwargs
        for env_id in group[1:]:
            kwargs = gym.spec(env_id).kwargs
            differ = {k for k in {*kwargs, *first} if kwargs.get(k) != first.get(k)}
            assert differ == {"reward_scale_m"}, differ


@pytest.mark.parametrize("env_id", [env_id for group in GROUPS for env_id in group])
def test_the_reward_threshold_is_the_stored_reference_returns_mean_rounded_down(env_id):
    returns = _stored()[env_id]
    assert len(returns) == RIGS
    assert gym.spec(env_id).reward_threshold == math.floor(np.mean(returns)), np.mean(returns)


@pytest.mark.slow
@pytest.mark.parametrize("group", GROUPS, ids=lambda group: "+".join(env_id.rsplit("-", 1)[1] for env_id in group))
def test_stored_returns_rerun_to_their_stored_values(group):
    """The returns of the first seed and of the group's lowest and highest, run again: a change of
    the physics, the base or the reward moves them (then rerun this file as a script and check the
    thresholds)."""
    stored = _stored()
    first = stored[group[0]]
    rerun = sorted({0, int(np.argmin(first)), int(np.argmax(first))})
    fresh, whole = _returns(group, [FIRST_SEED + i for i in rerun])
    for env_id in group:
        assert whole == [_stored("whole_steps")[env_id][i] for i in rerun], env_id
    for env_id in group:
        np.testing.assert_allclose(fresh[env_id], [stored[env_id][i] for i in rerun], rtol=1e-9, err_msg=env_id)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", REFERENCES)
def test_stored_score_reference_returns_rerun_to_their_stored_values(env_id):
    """The shipped policy's returns of the first seed and of its lowest and highest, run again, and
    their whole-episode steps (microg_env/scores.py's references)."""
    stored, steps = _stored("policy_returns")[env_id], _stored("whole_steps")[env_id]
    rerun = sorted({0, int(np.argmin(stored)), int(np.argmax(stored))})
    fresh, whole = _policy_returns(env_id, [FIRST_SEED + i for i in rerun])
    np.testing.assert_allclose(fresh, [stored[i] for i in rerun], rtol=1e-9)
    assert whole == [steps[i] for i in rerun]


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


if __name__ == "__main__":  # measure the hundred returns again and store them
    seeds = list(range(FIRST_SEED, FIRST_SEED + RIGS))
    returns, whole_steps = {}, {}
    for group in GROUPS:
        measured, whole = _returns(group, seeds)
        returns |= measured
        whole_steps |= dict.fromkeys(group, whole)
    policy_returns = {}
    for env_id in REFERENCES:
        policy_returns[env_id], whole = _policy_returns(env_id, seeds)
        assert whole == whole_steps[env_id], env_id
    header = {"measured": f"python {Path(*Path(__file__).parts[-3:])}", "seeds": [seeds[0], seeds[-1]]}
    tables = {"returns": returns, "whole_steps": whole_steps, "policy_returns": policy_returns}
    RETURNS.write_text(json.dumps(header | tables, indent=1) + "\n")
    for env_id, each in returns.items():
        print(f"{env_id}: mean {np.mean(each):.2f} +- {np.std(each) / np.sqrt(len(each)):.2f}", file=sys.stderr)
    for env_id, each in policy_returns.items():
        zero = np.mean(whole_steps[env_id]) - np.mean(returns[env_id])
        one = np.mean(whole_steps[env_id]) - np.mean(each)
        print(f"{env_id}: shortfall {zero!r} (zero), {one!r} ({REFERENCES[env_id].one})", file=sys.stderr)
