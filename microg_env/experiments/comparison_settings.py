"""What ``microg compare`` may be asked: its first test seed, and the most seeds and workers a
comparison takes. Light to import: the ``microg`` command's parser reads them before
:mod:`microg_env.experiments.comparison` imports the controllers and the physics.
"""

#: First test seed: training seeds its environments from 0 (``n_envs`` of them), validation from 500.
TEST_SEED = 1000
#: Most seeds per scenario and worker processes a comparison takes.
MAX_SEEDS, MAX_WORKERS = 1000, 256
