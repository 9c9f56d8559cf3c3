"""The learning tasks' normalised score: an episode's return put on a scale where the task's base
(or the paper's PID) scores 0 and a stated reference scores 1.

A return is mostly the episode's length: every control period near x = 0 pays about 1 (Eq. of
``envs.period.x_reward``), so two draws of one task differ by a hundred or more in return while a
policy moves its own by a fraction of one (docs/environment.md, "Normalised score"). The score
therefore reads the return's *shortfall*: the steps a whole episode has (its scenario's control
periods over the decision period, rounded up: the most it can earn) minus the return. A period at
x = 0 falls short by 0; an episode that ends early falls short by every step it did not run. Over
the same seeds every controller has the same whole-episode steps, so a mean score over seeds is
the normalised mean return exactly:

    score = (S0 - S) / (S0 - S1),  S = whole-episode steps - return,

with S0 and S1 the base's and the reference's mean shortfall over the task's own draws, seeds
1000-1099 (the seeds of its ``reward_threshold``). The environment reports it in ``info`` at the
step that ends an episode by itself (terminated, or at its schedule's end, not at a step limit) on
a task made exactly as registered; ``normalized_score`` gives it from a mean shortfall.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import gymnasium as gym

#: The seeds the references' mean shortfalls are taken over (the reward thresholds').
REFERENCE_SEEDS = (1000, 1099)


@dataclass(frozen=True)
class ScoreReference:
    """What scores 0 and 1 on a task, and their mean shortfalls over :data:`REFERENCE_SEEDS`."""

    zero: str  # the controller that scores 0
    one: str  # the controller that scores 1
    zero_shortfall: float
    one_shortfall: float

    def score(self, shortfall: float) -> float:
        """The score of an episode (or a mean over episodes) that fell ``shortfall`` short."""
        return (self.zero_shortfall - shortfall) / (self.zero_shortfall - self.one_shortfall)


#: Each learning task's reference: its zero action (or the paper's PID) and its shipped policy, their
#: mean shortfalls on seeds 1000-1099 of its own draws, to 6 decimals (``python
#: tests/learning/test_reward_threshold.py`` measures them; tests/learning/reference_returns.json
#: holds each seed's returns and whole-episode steps).
REFERENCES = {
    "MicroGravityLanding-Residual-v7": ScoreReference("adaptive-dither", "residual-sac-setpoint", 1.378895, 1.171536),
    "MicroGravityLanding-GainScheduling-v1": ScoreReference("pid-dom", "gains-ppo", 28.710418, 19.043244),
    "MicroGravityLanding-Command-v1": ScoreReference("pid", "command-ppo", 147.948717, 76.761597),
}


def _task(settings):
    """``settings`` with its hidden entries in one order: a set, however they were listed."""
    return dataclasses.replace(settings, hidden_observations=tuple(sorted(settings.hidden_observations)))


@functools.cache
def _registered_tasks() -> dict:
    """Each scored id's task settings as registered, to the id."""
    from microg_env.task import TaskSettings

    return {_task(TaskSettings(**gym.spec(env_id).kwargs)): env_id for env_id in REFERENCES}


def scored_id(settings) -> str | None:
    """The id whose registered task ``settings`` (a :class:`~microg_env.task.TaskSettings`) are
    exactly, if it has a score; None otherwise (another keyword, another rig: another task)."""
    return _registered_tasks().get(_task(settings))


def normalized_score(env_id: str, mean_shortfall: float) -> float:
    """The score of ``env_id``'s episodes whose mean shortfall is ``mean_shortfall``."""
    if env_id not in REFERENCES:
        raise ValueError(f"no normalised score for {env_id!r}; scored: {', '.join(REFERENCES)}")
    return REFERENCES[env_id].score(mean_shortfall)
