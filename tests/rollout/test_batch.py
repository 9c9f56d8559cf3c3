"""Episodes as the rigs of one batch: the single environment's episodes, bit for bit."""

import pytest

from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.rollout.batch import evaluate_batch
from microg_env.rollout.episode import evaluate

SEEDS = range(40, 43)


@pytest.mark.parametrize("controller", ["pid", "residual-ppo"])
@pytest.mark.slow
def test_a_batched_evaluation_is_the_single_envs_episodes_one_after_another(controller):
    """Training validates on sampled schedules and drawn plants: each seed's rig draws the schedule
    and plant the single environment draws, and ends with the same metrics."""
    settings = {"scenario_sampler": "training", "domain_randomization": "full"}
    alone, alone_failures = evaluate(
        lambda: MicroGravityLandingEnv(**settings), make_controller(controller, 1e-3), SEEDS
    )
    batched, batched_failures = evaluate_batch(settings, make_controller(controller, 1e-3), SEEDS)
    assert [run.as_dict() for run in batched] == [run.as_dict() for run in alone]
    assert batched_failures == alone_failures
    assert len({run.impact_speed_m_s for run in batched}) == len(SEEDS)  # each rig its own schedule


def test_a_batched_evaluation_raises_what_its_controller_raises():
    class Broken:
        def reset(self, ids=None):
            pass

        def __call__(self, observation, info=None, ids=None):
            raise ZeroDivisionError("no")

    with pytest.raises(RuntimeError, match="ZeroDivisionError: no"):
        evaluate_batch({"scenario_sampler": "training"}, Broken(), SEEDS)
