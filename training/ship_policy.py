"""Ship a trained policy inside the package: copy a run's exported best policy, its training log and
its evaluations into ``microg_env/policies/<name>/``, where ``microg run --controller <name>`` and
``microg compare`` find it.

Run: ``python training/ship_policy.py logs/ppo/MicroGravityLanding-Command-v1_1 command-ppo``. The card
(``policy.json``) holds the exact command, seed and budget of the training and the steps and wall
time at which this (the best) model was saved; ``training.json`` adds the whole run's totals.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from microg_env.controllers.registry import policy_card
from microg_env.files import replace_folder
from microg_env.interface import CARD_FILE

PACKAGE_POLICIES = Path(__file__).resolve().parents[1] / "microg_env" / "policies"
#: What travels with a shipped policy: the exported network and card, stable-baselines3's files,
#: and the run's log and evaluations (the evidence of its budget).
RUN_FILES = ("train.log", "evaluations.json")
#: The whole run's totals, from its latest checkpoint's record.
TOTALS = ("timesteps", "wall_s", "sessions", "best_cost")


def ship(run: Path, name: str) -> Path:
    policy = run / "policy"
    policy_card(policy)  # a complete export (its card is written last)
    if not name.replace("-", "").isalnum():
        raise ValueError(f"policy name must be letters, digits and dashes, got {name!r}")

    def fill(staging: Path) -> None:
        for path in policy.iterdir():
            shutil.copy2(path, staging / path.name)
        for file in RUN_FILES:
            shutil.copy2(run / file, staging / file)
        latest = json.loads((run / "checkpoints" / "latest.json").read_text(encoding="utf-8"))
        totals = {key: latest[key] for key in TOTALS} | {"run": run.name}
        (staging / "training.json").write_text(json.dumps(totals, indent=2) + "\n", encoding="utf-8")

    PACKAGE_POLICIES.mkdir(exist_ok=True)
    out = replace_folder(PACKAGE_POLICIES / name, fill)
    assert (out / CARD_FILE).is_file()
    return out


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python training/ship_policy.py RUN_FOLDER NAME")
    print(f"shipped {ship(Path(sys.argv[1]), sys.argv[2])}")
