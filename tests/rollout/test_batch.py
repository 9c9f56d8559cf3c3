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


def test_one_compiled_model_is_one_batch_whatever_the_schedules_and_pads():
    """Specs that differ only in their schedule and the parameters an episode sets share a batch;
    a parameter the model compiles (the QZS's stiffness) or the randomisation starts another."""
    from microg_env.rollout.spec import RunSpec

    base = RunSpec("condition-1", "pid", 0)
    alike = [
        RunSpec("condition-3", "feedforward", 4, duration_s=3.0),
        RunSpec("heavy-second", "pid", 1, {"pad.stiffness_n_per_m": 9000.0, "lander.mass_kg": 600.0}),
        RunSpec("condition-2", "pid", 0, loads=((0.49, None),), descent_height_m=0.07),
    ]
    assert {spec.batch_key for spec in alike} == {base.batch_key}
    for other in (RunSpec("condition-1", "pid", 0, {"qzs.residual_stiffness_n_per_m": 35510.0}),
                  RunSpec("condition-1", "pid", 0, randomize=True)):  # fmt: skip
        assert other.batch_key != base.batch_key


@pytest.mark.slow
def test_a_batch_of_schedules_and_pads_runs_each_spec_as_it_runs_alone():
    """Each rig of a mixed batch (three schedules, two pads and landers, two controllers, each its
    own length) ends with the metrics ``run`` gives its spec on the single environment."""
    from microg_env.rollout.runner import run, run_all
    from microg_env.rollout.spec import RunSpec

    specs = [
        RunSpec(scenario, controller, seed, overrides, duration_s=duration)
        for scenario, duration in (("condition-1", 2.5), ("condition-2", 4.0), ("condition-3", 2.0))
        for controller in ("pid", "feedforward")
        for seed, overrides in ((1, {}), (2, {"pad.stiffness_n_per_m": 9000.0, "lander.mass_kg": 600.0}))
    ]
    assert len({spec.batch_key for spec in specs}) == 1
    batched = run_all(specs, workers=2)
    for spec, result in zip(specs, batched, strict=True):
        assert result.metrics.as_dict() == run(spec).metrics.as_dict(), spec
