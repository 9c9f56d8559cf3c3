"""Episodes as the rigs of one batch: the single environment's episodes, bit for bit."""

import numpy as np
import pytest

from microg_env.controllers import make_controller
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.rollout.batch import evaluate_batch
from microg_env.rollout.episode import evaluate

SEEDS = range(40, 43)


@pytest.mark.parametrize("controller", ["pid", "residual-sac-setpoint"])
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
    others = [
        RunSpec("condition-1", "pid", 0, {"qzs.residual_stiffness_n_per_m": 35510.0}),
        RunSpec("condition-1", "pid", 0, randomize=True),
        # episode parameters whose 0 removes a state of the compiled model (they shared a batch)
        RunSpec("condition-1", "pid", 0, {"qzs.guide_friction_n": 0.0}),
        RunSpec("condition-1", "pid", 0, {"servo.bristle_stiffness_n_m_per_rad": 0.0}),
        RunSpec("condition-1", "pid", 0, {"servo.torque_filter_s": 0.0}),
    ]
    for other in others:
        assert other.batch_key != base.batch_key, other.overrides


@pytest.mark.parametrize(
    "path", ["qzs.guide_friction_n", "servo.bristle_stiffness_n_m_per_rad", "servo.torque_filter_s"]
)
def test_a_rig_refuses_an_episode_that_removes_one_of_its_model_states(path):
    from microg_env.params import RigParams, parameter_paths, with_overrides
    from microg_env.scenarios import CONDITIONS
    from microg_env.sim.model import build_rig

    rig = build_rig(RigParams(), CONDITIONS[1].loads_kg)
    with pytest.raises(ValueError, match=rf"{path} \(to or from 0"):
        rig.check_episode_params(with_overrides(RigParams(), {path: 0.0}))
    other = 1.1 * parameter_paths(RigParams())[path]
    rig.check_episode_params(with_overrides(RigParams(), {path: other}))  # another value: an episode's to set


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
    batched = run_all(specs, workers=2, keep_trajectories=True)
    for spec, result in zip(specs, batched, strict=True):
        alone = run(spec)
        assert result.metrics.as_dict() == alone.metrics.as_dict(), spec
        assert result.trajectory.scenario == alone.trajectory.scenario  # the schedule as run alone records it
        assert result.reference.scenario == alone.reference.scenario  # cut from a longer one, its own schedule
        assert np.array_equal(result.reference.foot_height_m, alone.reference.foot_height_m)


def test_a_batch_refuses_episodes_that_mix_named_and_drawn_schedules():
    from microg_env.rollout.batch import EpisodeSpec, run_batch
    from microg_env.scenarios import CONDITIONS

    episodes = [EpisodeSpec("pid", None, 0), EpisodeSpec("pid", CONDITIONS[1], 1)]
    with pytest.raises(ValueError, match="a schedule each or none does"):
        run_batch(episodes, {"scenario_sampler": "training"})
