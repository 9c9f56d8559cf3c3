"""The vector environment: N rigs of ``MicroGravityLanding-v1`` stepped together on ``mujoco.batch``.

``gym.make_vec("microg_env:MicroGravityLanding-v1", num_envs=N, vectorization_mode="vector_entry_point")``
returns :class:`MicroGravityLandingVectorEnv`. It is the same :class:`~microg_env.envs.core.LandingCore`
as the single environment with N rigs and a :class:`~microg_env.sim.physics.BatchPhysics`: rig i
reset with seed s runs exactly the episode the single environment runs with seed s, observation
for observation, and its observations, rewards, terminations, truncations and infos are those a
``gymnasium.vector.SyncVectorEnv`` of single environments returns, in Gymnasium's layout
(info arrays with ``_key`` masks) and with its autoreset modes.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from microg_env import validate
from microg_env.envs.core import INFO_KEYS, SCORE_KEY, LandingCore, check_actions
from microg_env.envs.landing import render_settings
from microg_env.interface import action_space, observation_space
from microg_env.scenarios import Scenario
from microg_env.task import TaskSettings

#: Most rigs one vector environment steps (a batch's memory grows with it).
MAX_RIGS = 4096
#: A geom group MuJoCo's default visual options do not draw (they draw groups 0-2).
HIDDEN_GEOM_GROUP = 5


class MicroGravityLandingVectorEnv(VectorEnv):
    """N rigs of ``MicroGravityLanding-v1`` on ``mujoco.batch.Batch``.

    Takes the single environment's keyword arguments (rendering "rgb_array" only: ``render()``
    gives one frame per rig, Gymnasium's vector layout) and:

    | argument | default | meaning |
    |---|---|---|
    | ``num_envs`` | 1 | the number of rigs N |
    | ``autoreset_mode`` | ``NEXT_STEP`` | Gymnasium's ``AutoresetMode`` (or ``"NextStep"``, ``"SameStep"``...) |
    | ``scenarios`` | None | one ``Scenario`` per rig (instead of ``scenario``/``condition``) |
    | ``nthread`` | 0 | threads stepping the batch (0: one per core the process may run on) |
    | ``max_episode_steps`` | None | most steps an episode runs (``gym.make_vec`` passes the id's), as ``TimeLimit`` |

    ``reset(seed=s)`` seeds rig i with s + i (a list gives one seed per rig); each rig keeps its own
    generator through autoresets, as the single environments of a ``SyncVectorEnv`` do.
    ``options={"reset_mask": mask}`` resets only the rigs ``mask`` selects.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        scenarios: Sequence[Scenario] | None = None,
        nthread: int = 0,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera_name: str = "side",
        max_episode_steps: int | None = None,
        **kwargs: Any,
    ) -> None:
        self.num_envs = validate.integer("num_envs", num_envs, 1, MAX_RIGS)
        if render_mode is not None:
            validate.choice("render_mode", render_mode, tuple(self.metadata["render_modes"]))
        self._renderer = None
        try:
            self.autoreset_mode = AutoresetMode(autoreset_mode)
        except ValueError:
            modes = ", ".join(mode.value for mode in AutoresetMode)
            raise ValueError(f"autoreset_mode must be one of {modes}, got {autoreset_mode!r}") from None
        nthread = validate.integer("nthread", nthread, 0, 1024)
        self.core = LandingCore(self.num_envs, TaskSettings(**kwargs), scenarios, batched=True, nthread=nthread)
        if max_episode_steps is not None:  # as gym.make's TimeLimit: an episode ends at that many steps
            steps = validate.integer("max_episode_steps", max_episode_steps, 1)
            self.core.period_limit = min(steps * self.core.settings.decision_period, self.core.period_limit)
        self.settings = self.core.settings
        self._render_size, self._camera_name = render_settings(
            self.core.physics.model, render_mode, width, height, camera_name
        )
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        self.metadata["render_fps"] = round(1.0 / (self.settings.control_period_s * self.settings.decision_period))
        self.render_mode = render_mode
        self.single_action_space = action_space(self.settings.action_mode)
        self.single_observation_space = observation_space()
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._all = np.arange(self.num_envs)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._seeds: list[int | None] = [None] * self.num_envs
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._started = np.zeros(self.num_envs, dtype=bool)  # rigs reset at least once

    @property
    def np_random_seed(self) -> tuple[int | None, ...]:
        """Each rig's seed (None: drawn from the operating system's entropy; -1 before any reset)."""
        return tuple(-1 if rng is None else seed for rng, seed in zip(self._rngs, self._seeds, strict=True))

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None):
        seeds = self._seed_list(seed)
        mask = np.ones(self.num_envs, dtype=bool)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"])
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({self.num_envs},) with a True, got {mask!r}"
                )
        ids = self._all[mask]
        previous = list(self._rngs), list(self._seeds)
        try:
            for i in ids:
                if seeds[i] is not None or self._rngs[i] is None:
                    self._rngs[i], self._seeds[i] = seeding.np_random(seeds[i])
            self.core.reset(ids, self._rngs)  # draws and checks before it writes
        except BaseException:  # a failed reset leaves every rig as it was
            self._rngs, self._seeds = previous
            raise
        self._autoreset[ids] = False
        self._started[ids] = True
        return self.core.shown(), self._info(ids, np.zeros(ids.size, dtype=np.int64))

    def _seed_list(self, seed: int | Sequence[int | None] | None) -> list[int | None]:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            base = validate.integer("seed", int(seed), 0)
            return [base + i for i in range(self.num_envs)]
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(f"seed must be an int or one seed per rig ({self.num_envs}), got {len(seeds)}")
        return [None if s is None else validate.integer("seed", int(s), 0) for s in seeds]

    def step(self, actions):
        if not self._started.all():
            raise ResetNeeded(f"reset rigs {self._all[~self._started].tolist()} before step()")
        core, n = self.core, self.num_envs
        values = check_actions(actions, self.action_space.shape).reshape(n, -1)  # a row of numbers per rig
        rewards = np.zeros(n)
        codes = np.zeros(n, dtype=np.int64)
        truncated = np.zeros(n, dtype=bool)
        resetting = self._autoreset if self.autoreset_mode == AutoresetMode.NEXT_STEP else np.zeros(n, dtype=bool)
        if self.autoreset_mode == AutoresetMode.DISABLED and self._autoreset.any():
            raise ValueError(
                f"rigs {self._all[self._autoreset].tolist()} ended: reset them (options={{'reset_mask': ...}}) "
                "before stepping with autoreset_mode Disabled"
            )
        stepping = self._all[~resetting]
        if resetting.any():
            core.reset(self._all[resetting], self._rngs)
        if stepping.size:
            reward, code, cut, _ = core.step(stepping, values[stepping].reshape(-1), self._rngs)
            rewards[stepping], codes[stepping], truncated[stepping] = reward, code, cut
        terminated = codes != 0
        ended = terminated | truncated
        observations = core.shown()
        info = self._info(self._all, codes)
        scores = core.scores(self._all, codes, truncated) if core.score is not None and ended.any() else None
        scored = scores is not None and not np.isnan(scores).all()
        if scored:  # the scores of the rigs that ended by themselves, before a reset clears their returns
            info[SCORE_KEY], info[f"_{SCORE_KEY}"] = np.nan_to_num(scores), ~np.isnan(scores)
        if self.autoreset_mode == AutoresetMode.SAME_STEP and ended.any():
            done = self._all[ended]
            final_obs = np.full(n, None, dtype=object)
            for i in done:
                final_obs[i] = observations[i].copy()
            final_info = self._info(done, codes[done])
            if scored:
                final_info[SCORE_KEY], final_info[f"_{SCORE_KEY}"] = info.pop(SCORE_KEY), info.pop(f"_{SCORE_KEY}")
            core.reset(done, self._rngs)
            observations[done] = core.shown(done)
            after = core.info(done, np.zeros(done.size, dtype=np.int64))
            for key in INFO_KEYS:
                info[key][done] = after[key]
            info |= {"final_obs": final_obs, "_final_obs": ended.copy(), "final_info": final_info}
            info["_final_info"] = ended.copy()
        else:
            self._autoreset = ended
        return observations, rewards, terminated, truncated, info

    def _info(self, ids: np.ndarray, codes: np.ndarray) -> dict[str, np.ndarray]:
        """Gymnasium's vector info of the rigs ``ids``: every key an array over all rigs (0 or None
        for the others) with its ``_key`` mask."""
        values = self.core.info(ids, codes)
        info: dict[str, np.ndarray] = {}
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[ids] = True
        for key in INFO_KEYS:
            value = values[key]
            if ids.size == self.num_envs:
                array = value
            else:
                array = (
                    np.full(self.num_envs, None, dtype=object)
                    if value.dtype == object
                    else np.zeros(self.num_envs, dtype=value.dtype)
                )
                array[ids] = value
            info[key] = array
            info[f"_{key}"] = mask.copy()
        return info

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One RGB frame per rig, (height, width, 3) uint8, from ``camera_name``: each rig's
        positions and its weights' colours (a weight not yet placed drawn faint) written into one
        offscreen scene in turn."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to gym.make_vec")
            return None
        physics = self.core.physics
        if self._renderer is None:
            model = copy.deepcopy(physics.model)  # its colours change per rig; the batch's model stays
            width, height = self._render_size
            self._renderer = (model, mujoco.MjData(model), mujoco.Renderer(model, height=height, width=width))
        model, data, renderer = self._renderer
        colours, groups = physics.field("geom_rgba"), physics.model.geom_group
        frames = []
        for rig in range(self.num_envs):
            data.qpos[:] = physics.qpos[rig]
            model.geom_rgba[:] = colours[rig]
            # a weight beyond the rig's schedule (alpha 0) would still cast a shadow: a hidden group
            model.geom_group[:] = np.where(colours[rig][:, 3] == 0.0, HIDDEN_GEOM_GROUP, groups)
            mujoco.mj_fwdPosition(model, data)
            renderer.update_scene(data, camera=self._camera_name)
            frames.append(renderer.render())
        return tuple(frames)

    def close_extras(self, **kwargs: Any) -> None:
        """The renderer, if any; the batch goes with the environment."""
        if self._renderer is not None:
            self._renderer[2].close()
            self._renderer = None
