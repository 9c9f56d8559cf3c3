"""The ``microg`` commands on learned controllers: ``train`` and ``compare``."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from microg_env.cli.common import (
    ProgressStream,
    add_duration_option,
    check_writable_folder,
    comma_list,
    positive_int,
    seed_number,
)
from microg_env.controllers.registry import CONTROLLER_NAMES


def _cmd_train(args: argparse.Namespace) -> int:
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401
        from tqdm import tqdm

        from microg_env.learning.train import TrainingInterrupted, TrainSettings, resolve, resumed_run, train
    except ImportError:
        raise ValueError("microg train needs the train extra: pip install 'microg-env[train]'") from None
    settings = TrainSettings(
        algo=args.algo,
        env_id=args.env,
        seed=args.seed,
        timesteps=args.timesteps,
        n_envs=args.n_envs,
        hyperparams=args.hyperparams,
        log_folder=args.log_folder,
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        checkpoint_freq=args.checkpoint_freq,
        command=" ".join(["microg", *map(shlex.quote, args.argv)]),
    )
    resume = None
    if args.resume is not None:
        resume = Path(args.resume)
        if not (args.resume.strip() and resume.is_dir()):
            raise ValueError(f"--resume {args.resume!r}: no such run folder")
        resumed_run(resume, settings)  # a run that cannot be continued is named before anything is written
    else:
        try:
            resolve(settings)  # a bad file or entry is named before anything is written
        except ValueError as error:
            raise ValueError(f"--hyperparams: {error}" if args.hyperparams is not None else str(error)) from None
        check_writable_folder(args.log_folder, "--log-folder")
    stream = ProgressStream(sys.stderr)
    with tqdm(total=0, unit="step", unit_scale=True, desc=f"train {args.algo}", file=stream, disable=args.quiet) as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        def log(line: str) -> None:
            bar.write(line, file=sys.stdout)

        try:
            folder = train(settings, resume, progress, log)
        except TrainingInterrupted as stop:
            bar.write(f"microg train: {stop}", file=sys.stderr)
            return 130
    print(f"wrote {folder}")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from microg_env.analysis import comparison, comparison_report
    from microg_env.controllers.registry import CONTROLLER_NAMES, check_controller_name
    from microg_env.scenarios import comparison_scenarios

    controllers = args.controllers or list(CONTROLLER_NAMES)
    for name in controllers:
        try:
            check_controller_name(name)
        except ValueError as error:
            raise ValueError(f"--controllers: {error}") from None
    known = comparison_scenarios()
    scenarios = args.scenarios or list(known)
    for name in scenarios:
        if name not in known:
            raise ValueError(f"--scenarios: scenario must be one of {', '.join(known)}, got {name!r}")
    if args.out is not None:
        comparison_report.figure_class()  # fail now, not after the runs, if matplotlib is missing
        comparison_report.check_output(args.out)
    try:
        from tqdm import tqdm
    except ImportError:
        raise ValueError("microg compare needs the report extra: pip install 'microg-env[report]'") from None
    total = len(dict.fromkeys(controllers)) * len(scenarios) * args.seeds
    with tqdm(total=total, unit="episode", desc="compare", file=ProgressStream(sys.stderr), disable=args.quiet) as bar:
        result = comparison.compare(
            controllers,
            scenarios,
            seeds=args.seeds,
            first_seed=args.first_seed,
            randomize=args.randomize,
            duration_s=args.duration,
            workers=args.workers,
            progress=bar.update,
        )
    if args.json:
        print(json.dumps(result.as_dict(), indent=2))
    else:
        print(comparison_report.render_markdown(result))
    if args.out is not None:
        comparison_report.write(result, args.out)
        print(f"wrote {args.out}", file=sys.stderr if args.json else sys.stdout)
    return 0


def add_commands(commands) -> None:
    """train and compare."""
    train = commands.add_parser(
        "train",
        help="train a learned controller with stable-baselines3 (rl-baselines3-zoo layout)",
        description="Train PPO or SAC on MicroGravityLanding-v1 with the hyperparameters of training/hyperparams/"
        "<algo>.yml (packaged), into logs/<algo>/<env>_<n>/: config, best model, normalisation, checkpoints, "
        "TensorBoard events, monitor files, evaluations by the project's metrics and the exported policy.",
    )
    train.add_argument("--algo", choices=("ppo", "sac"), default="ppo", help="algorithm (stable-baselines3)")
    train.add_argument("--env", default="MicroGravityLanding-v1", help="environment id")
    train.add_argument("--seed", type=seed_number, default=0, help="seed of the model and the training environments")
    train.add_argument("--timesteps", type=positive_int, metavar="N", help="steps to train (default: the file's)")
    train.add_argument("--n-envs", type=positive_int, metavar="N", help="environments (default: the file's)")
    train.add_argument(
        "-conf",
        "--hyperparams",
        metavar="FILE",
        help="hyperparameter file in rl-baselines3-zoo's format (default: the packaged <algo>.yml)",
    )
    train.add_argument("--log-folder", default="logs", metavar="DIR", help="where runs go (default logs)")
    from microg_env.learning.train import TrainSettings

    defaults = TrainSettings(algo="ppo")
    train.add_argument(
        "--eval-freq",
        type=positive_int,
        default=defaults.eval_freq,
        metavar="N",
        help=f"steps between evaluations (default {defaults.eval_freq})",
    )
    train.add_argument(
        "--eval-episodes",
        type=positive_int,
        default=defaults.eval_episodes,
        metavar="N",
        help=f"validation episodes per evaluation (default {defaults.eval_episodes})",
    )
    train.add_argument(
        "--checkpoint-freq",
        type=positive_int,
        default=defaults.checkpoint_freq,
        metavar="N",
        help=f"steps between checkpoints (default {defaults.checkpoint_freq})",
    )
    train.add_argument(
        "--resume", metavar="RUN", help="continue the run in folder RUN from its last checkpoint (to --timesteps)"
    )
    train.add_argument("--quiet", action="store_true", help="no progress bar")
    train.set_defaults(handler=_cmd_train)

    compare = commands.add_parser(
        "compare",
        help="compare controllers on the same held-out scenarios and seeds",
        description="Run every controller on the paper's conditions and the held-out scenarios, on the same seeds "
        "(and, with --randomize, the same randomised plants); print mean, std, worst case and failure rate of the "
        "compensation error, residual gravity, x in free fall and at the collision, and the deformation fidelity.",
    )
    compare.add_argument(
        "--controllers",
        type=comma_list,
        metavar="A,B,...",
        help=f"controllers or policy folders (default: {','.join(CONTROLLER_NAMES)})",
    )
    compare.add_argument(
        "--scenarios",
        type=comma_list,
        metavar="A,B,...",
        help="condition-1, condition-2, condition-3, heavy-second, light-long (default: all)",
    )
    compare.add_argument("--seeds", type=positive_int, default=5, metavar="N", help="seeds per scenario (default 5)")
    compare.add_argument(
        "--first-seed", type=seed_number, default=1000, metavar="S", help="first seed (default 1000, above training's)"
    )
    compare.add_argument("--randomize", action="store_true", help="randomised plants, drawn from each seed")
    add_duration_option(compare, "cap on each episode's simulated time (default: the scenario's)")
    compare.add_argument("--workers", type=positive_int, default=1, metavar="N", help="parallel processes (default 1)")
    compare.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    compare.add_argument(
        "--out", metavar="DIR", help="also write comparison.md, comparison.json and figures to DIR (replaced)"
    )
    compare.add_argument("--quiet", action="store_true", help="no progress bar")
    compare.set_defaults(handler=_cmd_compare)
