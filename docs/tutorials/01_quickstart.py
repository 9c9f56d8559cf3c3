"""Tutorial 1, the quick start: make the environment, drive it with a controller, plot the landing.

Run it as a script (``python docs/tutorials/01_quickstart.py``, about 10 s on a laptop CPU) or open
it as a notebook: each ``# %%`` starts a cell (VS Code, PyCharm and Jupytext read them). It needs
the report extra: ``pip install 'microg-env[report]'``.
"""

# %% What the run writes, and how long a run is (the paper's tests are 30 s).
import argparse
from pathlib import Path

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--out", default="tutorial-output", help="folder for the figure")
parser.add_argument("--duration", type=float, default=30.0, help="simulated seconds")
args = parser.parse_args()
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)

# %% The environment: importing microg_env registers it with Gymnasium.
import gymnasium as gym

import microg_env  # noqa: F401

env = gym.make("microg_env:MicroGravityLanding-v1", condition=1)
print(f"observation {env.observation_space.shape}, action {env.action_space.shape}, one step = {env.unwrapped.dt} s")

# %% A controller: the paper's PID (Section 4.1), which reads the environment's observations. Any
# object with `reset()` and `__call__(observation, info) -> action` drives the rig the same way.
from microg_env.controllers import make_controller

controller = make_controller("pid", env.unwrapped.settings.control_period_s)

# %% One episode by hand, as with any Gymnasium environment.
observation, info = env.reset(seed=0)
controller.reset()
steps = round(args.duration / env.unwrapped.dt)
for _ in range(steps):
    observation, reward, terminated, truncated, info = env.step(controller(observation, info))
    if terminated or truncated:
        break
print(f"t = {info['time_s']:.2f} s: x = {info['x_m'] * 1e6:+.3f} µm, pad force {info['pad_force_n']:.2f} N")

# %% The same episode recorded, with its ideal-microgravity reference and the paper's metrics.
from microg_env.rollout.episode import run_with_metrics

trajectory, reference, metrics = run_with_metrics(env, controller, seed=0, duration_s=args.duration)
print(f"compensation error per stage: {[f'{e:+.3f} %' for e in metrics.compensation_error_pct]}")
print(f"max |x| in free fall: {metrics.flexible_unit_excursion_free_fall_m * 1e6:.2f} µm")

# %% The figure `microg run --plot` draws: height, x, acceleration and pad force, events marked.
from microg_env.analysis.plots import plot_run

plot_run(trajectory, reference, "condition 1, pid, seed 0", out / "quickstart.png")
print(f"wrote {out / 'quickstart.png'}")
env.close()
