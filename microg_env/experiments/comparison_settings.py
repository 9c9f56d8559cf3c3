"""What ``microg compare`` may be asked: its seed ranges, and the most seeds and workers a
comparison takes. Light to import: the ``microg`` command's parser reads them before
:mod:`microg_env.experiments.comparison` imports the controllers and the physics.
"""

from microg_env.scenarios import comparison_scenarios

#: First test seed: training seeds its environments from 0 (``n_envs`` of them), validation from 500.
TEST_SEED = 1000
#: First confirmation seed: the range no design decision looks at, run once per release and
#: reported as such (``microg compare --confirmation``).
CONFIRMATION_SEED = 1_000_000
#: Most seeds per scenario and worker processes a comparison takes.
MAX_SEEDS, MAX_WORKERS = 1000, 256


def scenario_seeds(scenario: str, first_seed: int, seeds: int) -> tuple[int, ...]:
    """The seeds ``scenario`` runs: ``seeds`` of its own block of :data:`MAX_SEEDS`, the
    ``k``-th scenario of :func:`~microg_env.scenarios.comparison_scenarios` from
    ``first_seed + k * MAX_SEEDS``. No two scenarios share a seed, so none share a drawn plant."""
    start = first_seed + tuple(comparison_scenarios()).index(scenario) * MAX_SEEDS
    return tuple(range(start, start + seeds))
