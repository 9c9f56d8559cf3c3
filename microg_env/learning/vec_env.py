"""The batched vector environment as stable-baselines3's ``VecEnv``.

:class:`BatchedVecEnv` adapts a :class:`~microg_env.envs.vector.MicroGravityLandingVectorEnv` (in
Gymnasium's same-step autoreset mode) to SB3's contract: ``reset()`` returns the observations only
and seeds rig i with ``seed + i`` after ``seed(seed)``; ``step_wait()`` returns per-rig info
dictionaries in which an episode's last step carries ``terminal_observation`` and
``TimeLimit.truncated``, and its observation is already the next episode's. With the same seeds it
gives the episodes ``make_vec_env`` builds from single environments, on one ``mujoco.batch``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from microg_env.envs.core import INFO_KEYS, SCORE_KEY
from microg_env.envs.vector import MicroGravityLandingVectorEnv


class BatchedVecEnv(VecEnv):
    """N rigs on ``mujoco.batch`` behind stable-baselines3's ``VecEnv`` interface."""

    def __init__(self, env: MicroGravityLandingVectorEnv) -> None:
        if env.autoreset_mode != AutoresetMode.SAME_STEP:
            raise ValueError(f"BatchedVecEnv needs autoreset_mode SameStep, got {env.autoreset_mode.value}")
        self.env = env
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self._actions: np.ndarray | None = None

    @classmethod
    def make(cls, num_envs: int, **env_kwargs: Any) -> BatchedVecEnv:
        """A batched ``MicroGravityLanding-v1`` of ``num_envs`` rigs with these env keyword arguments."""
        return cls(MicroGravityLandingVectorEnv(num_envs, autoreset_mode=AutoresetMode.SAME_STEP, **env_kwargs))

    def reset(self) -> np.ndarray:
        observations, info = self.env.reset(seed=list(self._seeds), options=self._options[0] or None)
        self.reset_infos = _per_rig(info)
        self._reset_seeds()
        self._reset_options()
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).reshape(self.num_envs, -1)

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, terminated, truncated, info = self.env.step(self._actions)
        infos = _per_rig(info)
        cut = (truncated & ~terminated).tolist()
        if "final_info" in info:  # an ended rig's info is its last step's; the reset's goes to reset_infos
            final = _per_rig(info["final_info"])
            for i in np.flatnonzero(info["_final_obs"]):
                self.reset_infos[i] = infos[i]
                infos[i] = final[i] | {"terminal_observation": info["final_obs"][i]}
        for rig_info, was_cut in zip(infos, cut, strict=True):
            rig_info["TimeLimit.truncated"] = was_cut
        return observations, rewards.astype(np.float32), terminated | truncated, infos

    def close(self) -> None:
        self.env.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.env, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.env, attr_name, value)  # the rigs share one environment object

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Calls the method once, on the one environment all the rigs share."""
        result = getattr(self.env, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]


def _per_rig(info: dict[str, Any]) -> list[dict[str, Any]]:
    """Gymnasium's vector info (arrays over rigs) as one dictionary per rig, as SB3 expects: every
    rig's state, and the normalised score of a rig whose episode ended (where its mask is set)."""
    columns: Sequence[list] = [info[key].tolist() for key in INFO_KEYS]
    rigs = [dict(zip(INFO_KEYS, values, strict=True)) for values in zip(*columns, strict=True)]
    if SCORE_KEY in info:
        for i in np.flatnonzero(info[f"_{SCORE_KEY}"]):
            rigs[i][SCORE_KEY] = float(info[SCORE_KEY][i])
    return rigs
