"""What ``microg train`` may be asked: its algorithms, environments and bounds, and a run's
settings (:class:`TrainSettings`, its ``args.yml``). Light to import: the ``microg`` command's
parser reads them before the training's modules (:mod:`microg_env.learning.train`,
:mod:`microg_env.learning.hyperparams`) import the controllers and the physics.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Algorithms ``microg train`` runs (stable-baselines3's PPO and SAC, sb3-contrib's TQC and CrossQ).
ALGORITHMS = ("ppo", "sac", "tqc", "crossq")
#: The sb3-contrib algorithms among them, by their class names there.
CONTRIB_ALGORITHMS = {"tqc": "TQC", "crossq": "CrossQ"}
#: Most environments a run steps (the CLI's --n-envs cap: rigs of one batch).
MAX_ENVS = 256
#: Most validation episodes a run takes.
MAX_EVAL_EPISODES = 1000
#: The environments ``microg train`` trains on: the three learning tasks (the first, the card's
#: action, by default) and the residual's v6, on which the shipped ``residual-sac-setpoint`` trained.
ENV_IDS = (
    "MicroGravityLanding-Command-v1",
    "MicroGravityLanding-GainScheduling-v1",
    "MicroGravityLanding-Residual-v7",
    "MicroGravityLanding-Residual-v6",
)
#: What training needs installed, named when it is missing.
TRAIN_EXTRA = "microg train needs the train extra: pip install 'microg-env[train]'"


@dataclass(frozen=True)
class TrainSettings:
    """What a run is asked to do (``args.yml``)."""

    algo: str = "ppo"
    env_id: str = ENV_IDS[0]
    seed: int = 0
    timesteps: int | None = None  # None: the hyperparameter file's n_timesteps
    n_envs: int | None = None  # None: the hyperparameter file's n_envs
    hyperparams: str | None = None  # None: the packaged microg_env/hyperparams/<algo>.yml
    log_folder: str = "logs"
    eval_freq: int = 100_000  # environment steps (all environments together) between evaluations
    eval_episodes: int = 5
    checkpoint_freq: int = 100_000  # environment steps between checkpoints
    rig: str | None = None  # a rig file, whose parameters become the env_kwargs' params
    command: str = ""
