"""The returns table of the learning tasks (MicroGravityLanding-Command-v1, -GainScheduling-v1, -Residual-v7 to
-v1): what each controller earns.

Every controller runs in the id's environment with its defaults (on a residual id a residual x setpoint on
`adaptive`, held 5 control periods: +-1 um in v1, +-3 um high-passed at 2 Hz in v2, twice in v3,
the absolute positions hidden from the agent in v4; v5 on `adaptive-dither`, gated to the contact,
the agent reading the paper's sensors; v6 gated on the high-passed setpoint; v7 scored at x0 =
1 um; plants and drives drawn by ``DomainRandomization.full()``): ``random`` (uniform residuals), ``zero
residual`` (the id's base alone), the other classical controllers as the base with a zero residual
(an all-zero residual is exactly its base) and learned policies (shipped names or policy folders
trained on this task). A
return is the episode's undiscounted sum of rewards; the table gives mean ± std over seeds from
1000, the comparison's test seeds. On the gain-scheduling id the rows are ``zero action`` (its base PID
as tuned) and the other PID as its base. On the command id, which has no base, each classical
controller commands the drive itself (at the drive's own action unit, reading every entry: neither
changes the draws) and ``pid`` is the ``reference`` row. ``training`` draws the id's own schedules;
the other scenarios are the comparison's, outside the training draws. The id's ``reward_threshold``
is the zero residual's (zero action's, the reference's) mean return on ``training`` over 100 seeds
(``--seeds 100 --scenarios training``), rounded down: a policy above it earns more than its base
controller alone (the paper's PID) on the task it was trained on. Returns grow with an episode's
length, so compare controllers on the same seeds.

Run: ``python training/returns_table.py [--env ID] [--seeds 5] [--scenarios training,condition-1] [--policies NAME]``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

import gymnasium as gym
import numpy as np

import microg_env  # noqa: F401  (registers the ids)
from microg_env.controllers.registry import (
    ACTING_KEYS,
    check_policy_folder,
    is_policy_folder,
    make_controller,
    shipped_policy_folder,
)
from microg_env.experiments.comparison import TEST_SEED
from microg_env.interface import GAIN_BASES, MAX_SPEED_M_S, action_size
from microg_env.learning.train import ENV_IDS as TRAINED_IDS
from microg_env.scenarios import comparison_scenarios
from microg_env.task import ActingSettings, TaskSettings


def action_mode(env_id: str) -> str:
    """What ``env_id``'s action is (a command id registers the default: the speed)."""
    return ActingSettings.of(gym.spec(env_id).kwargs).action_mode


def is_command_id(env_id: str) -> bool:
    """Whether ``env_id`` is a learning task whose action is the drive's speed command (no base
    controller): a speed id with draws of its own (``MicroGravityLanding-v1`` has none)."""
    return action_mode(env_id) == "speed" and bool(gym.spec(env_id).kwargs)


#: The learning tasks' ids (those ``microg train`` trains on): the residual ones, the newest first (the
#: default), then the gain-scheduling one and the command one.
ENV_IDS = (
    *sorted((env_id for env_id in TRAINED_IDS if action_mode(env_id) == "residual"), reverse=True),
    *[env_id for env_id in TRAINED_IDS if action_mode(env_id) == "gains"],
    *[env_id for env_id in TRAINED_IDS if is_command_id(env_id)],
)
#: A command id's classical rows run at the drive's own action unit, every entry shown.
DRIVE_ACTING = {"speed_limit_m_s": MAX_SPEED_M_S, "hidden_observations": ()}
#: The classical controllers run as the base with a zero residual, a row each.
CLASSICAL = ("pid", "feedforward", "adaptive", "adaptive-dither", "oracle")
SCENARIOS = ("training", *comparison_scenarios())


def episode_return(env: gym.Env, act: Callable[[np.ndarray], np.ndarray], seed: int) -> float:
    """The undiscounted return of one episode of ``env`` reset with ``seed``, actions ``act(obs)``."""
    obs, _ = env.reset(seed=seed)
    total, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, _ = env.step(act(obs))
        total += float(reward)
        done = terminated or truncated
    return total


def base_rows(env_id: str) -> dict[str, str]:
    """The classical controllers' rows of ``env_id``'s table, by name: the id's own base controller
    is its ``zero residual`` (``zero action``) row; a gains id's bases are the PIDs; on a command id
    the paper's PID is the ``reference``."""
    kwargs = gym.spec(env_id).kwargs
    if is_command_id(env_id):
        # the oracle, told each episode's plant by a base's environment, has none to tell it here
        return {("pid (reference)" if name == "pid" else name): name for name in CLASSICAL if name != "oracle"}
    own, gains = kwargs["base_controller"], kwargs["action_mode"] == "gains"
    zero = "zero action" if gains else "zero residual"
    return {(f"{zero} ({name})" if name == own else name): name for name in (GAIN_BASES if gains else CLASSICAL)}


def make_env(env_id: str, scenario: str, base: str | None = None) -> gym.Env:
    """The id's environment on ``scenario`` ("training": its own draws) with ``base`` (by default the
    id's own) under the residual; on a command id, for a classical ``base``, at the drive's own
    action unit with every entry shown (:data:`DRIVE_ACTING`)."""
    if is_command_id(env_id):
        kwargs = DRIVE_ACTING if base is not None else {}
    else:
        kwargs = {"base_controller": gym.spec(env_id).kwargs["base_controller"] if base is None else base}
    if scenario == "training":
        return gym.make(env_id, **kwargs)
    return gym.make(env_id, **kwargs, scenario_sampler=None, scenario=comparison_scenarios()[scenario])


def policy_actor(env_id: str, name: str) -> Callable[[np.ndarray], np.ndarray]:
    """The deterministic action of the policy ``name`` (shipped or a folder) trained on ``env_id``'s task."""
    folder = name if is_policy_folder(name) else shipped_policy_folder(name)
    card, policy = check_policy_folder(folder)
    trained, task = _acting(card["env_kwargs"]), _acting(gym.spec(env_id).kwargs)
    for key in ACTING_KEYS:
        if trained[key] != task[key]:
            raise ValueError(
                f"policy {name!r} was trained with {key} {_shown(trained[key])!r}, not {env_id}'s {_shown(task[key])!r}"
            )
    return lambda obs: policy.predict(obs, deterministic=True)[0].reshape(-1)


def _acting(env_kwargs: dict) -> dict[str, object]:
    """The acting settings of ``env_kwargs`` as compared: a key left out as its default, a list of
    names (JSON keeps a tuple as a list) as the set of them."""
    settings = TaskSettings(**{key: env_kwargs[key] for key in ACTING_KEYS if key in env_kwargs})
    values = {key: getattr(settings, key) for key in ACTING_KEYS}
    return {key: frozenset(value) if isinstance(value, tuple) else value for key, value in values.items()}


def _shown(value: object) -> object:
    return sorted(value) if isinstance(value, frozenset) else value


def returns(env_id: str, row: str, scenario: str, seeds: int) -> list[float]:
    """The returns of controller ``row`` (a :func:`base_rows` name, "random" or a policy) on ``scenario``."""
    bases = base_rows(env_id)
    env = make_env(env_id, scenario, bases.get(row))
    size = action_size(env.unwrapped.settings.action_mode)
    values = []
    for seed in range(TEST_SEED, TEST_SEED + seeds):
        if row == "random":
            rng = np.random.default_rng(seed)
            act = lambda obs, rng=rng: rng.uniform(-1.0, 1.0, size=size).astype(np.float32)  # noqa: E731
        elif row in bases and is_command_id(env_id):
            controller = make_controller(bases[row], env.unwrapped.settings.control_period_s)
            act = lambda obs, c=controller: c(obs[None])[0].astype(np.float32)  # noqa: E731
        elif row in bases:
            act = lambda obs: np.zeros(size, dtype=np.float32)  # noqa: E731
        else:
            act = policy_actor(env_id, row)
        values.append(episode_return(env, act, seed))
    env.close()
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", choices=ENV_IDS, default=ENV_IDS[0], help=f"the task (default {ENV_IDS[0]})")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per scenario, from 1000 (default 5)")
    parser.add_argument("--scenarios", default=",".join(SCENARIOS), help="comma-separated (default: every one)")
    parser.add_argument("--policies", default="", help="learned policies trained on this task, comma-separated")
    args = parser.parse_args(argv)
    scenarios = args.scenarios.split(",")
    policies = list(filter(None, args.policies.split(",")))
    for name in policies:  # a policy of another task is refused before any row runs
        try:
            policy_actor(args.env, name)
        except ValueError as error:
            parser.error(f"--policies: {error}")
    rows = ["random", *base_rows(args.env), *policies]
    print("| controller | " + " | ".join(f"`{s}`" for s in scenarios) + " |")
    print("|---" * (len(scenarios) + 1) + "|")
    for row in rows:
        cells = []
        for scenario in scenarios:
            values = returns(args.env, row, scenario, args.seeds)
            cells.append(f"{np.mean(values):.1f} ± {np.std(values):.1f}")
        print(f"| {row} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
