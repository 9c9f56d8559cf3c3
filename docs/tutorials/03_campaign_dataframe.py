"""Tutorial 3: a small campaign on Ray, its table read into a pandas DataFrame and plotted.

The question, a small one: how does the pad's stiffness change the PID's and the feed-forward's
excursion of x at the collision? Twelve runs (two controllers, three stiffnesses, two seeds) of
condition 1 through its first contact. ``microg campaign FILE`` runs the same file the same way;
a campaign started again skips every run already stored.

Run it as a script (``python docs/tutorials/03_campaign_dataframe.py``, under a minute on two
cores) or as a notebook (``# %%`` cells). It needs the campaign extra: ``pip install
'microg-env[campaign]'``.
"""

# %% Settings.
import argparse
from pathlib import Path

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--out", default="tutorial-output", help="folder for the campaign and the figure")
parser.add_argument("--duration", type=float, default=7.0, help="simulated seconds per run")
args = parser.parse_args()
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)

# %% The campaign file: a base run, a grid to sweep, the seeds (docs/cli.md, "microg campaign").
campaign_file = out / "pad-stiffness.yml"
campaign_file.write_text(
    f"""name: pad-stiffness
description: x at the collision against the pad's stiffness, PID and feed-forward
base:
  scenario: condition-1
  duration_s: {args.duration}
sweep:
  controller: [pid, feedforward]
  pad.stiffness_n_per_m: [3000, 4666, 9387]
seeds: {{first: 1000, count: 2}}
""",
    encoding="utf-8",
)

# %% Run it on a local Ray instance (two CPUs): one row per run in Parquet, then one table.
from microg_env.experiments.campaign import Campaign
from microg_env.experiments.distributed import execute

campaign = Campaign.load(campaign_file)
summary = execute(campaign, out / "pad-stiffness", num_cpus=2)
print(f"{summary.done} runs stored, {summary.failed} failed, {summary.skipped} already there")

# %% Into pandas: swept settings keep their dotted names as columns.
import pandas as pd

table = pd.read_parquet(out / "pad-stiffness" / "results.parquet")
table["x_collision_um"] = table["flexible_unit_excursion_collision_m"] * 1e6
means = table.groupby(["controller", "pad.stiffness_n_per_m"])["x_collision_um"].agg(["mean", "std"])
print(means)

# %% Plotted: one line per controller, the seeds' spread as error bars.
from matplotlib.figure import Figure

figure = Figure(figsize=(5, 3.5), layout="constrained")
ax = figure.subplots()
for controller, rows in means.groupby(level="controller"):
    stiffness = rows.index.get_level_values("pad.stiffness_n_per_m")
    ax.errorbar(stiffness, rows["mean"], yerr=rows["std"], marker="o", capsize=3, label=controller)
ax.set_xlabel("pad stiffness K [N/m]")
ax.set_ylabel("max |x| during the collision [µm]")
ax.set_yscale("log")
ax.legend()
ax.grid(alpha=0.3)
figure.savefig(out / "pad-stiffness.png", dpi=110)
print(f"wrote {out / 'pad-stiffness.png'}")
