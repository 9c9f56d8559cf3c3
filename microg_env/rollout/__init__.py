"""Running episodes: one rig on the Gymnasium environment (:mod:`~microg_env.rollout.episode`),
many as rigs of one ``mujoco.batch`` (:mod:`~microg_env.rollout.batch`), and runs described by a
:class:`~microg_env.rollout.spec.RunSpec` (:mod:`~microg_env.rollout.runner`), each giving one
:class:`~microg_env.rollout.runner.RunResult`."""

from microg_env.rollout.runner import RunResult, run, run_all, run_many
from microg_env.rollout.spec import RunSpec

__all__ = ["RunResult", "RunSpec", "run", "run_all", "run_many"]
