"""The ``microg`` commands on learned controllers: ``train``, ``compare`` and ``export-onnx``."""

from __future__ import annotations

import argparse
import importlib.util
import json
import shlex
import sys
from pathlib import Path

from microg_env.cli.common import (
    MAX_SEED,
    add_duration_option,
    add_rig_option,
    check_writable_folder,
    comma_list,
    count,
    progress_bar,
    rig_overrides,
    seed_number,
)
from microg_env.experiments.comparison_settings import (
    CONFIRMATION_SEED,
    MAX_SEEDS,
    MAX_WORKERS,
    TEST_SEED,
    scenario_seeds,
)
from microg_env.imperfections import PRESETS
from microg_env.interface import CONTROLLER_NAMES, shipped_policies
from microg_env.learning.settings import (
    ALGORITHMS,
    CONTRIB_ALGORITHMS,
    MAX_ENVS,
    MAX_EVAL_EPISODES,
    TRAIN_EXTRA,
    TrainSettings,
)
from microg_env.scenarios import comparison_scenarios
from microg_env.validate import shown
from microg_env.workers import usable_cores

#: ``microg train``'s options that set a run (``args.yml``), by the TrainSettings field they fill.
_RUN_FIELDS = {
    "--algo": "algo",
    "--env": "env_id",
    "--seed": "seed",
    "--n-envs": "n_envs",
    "--hyperparams": "hyperparams",
    "--log-folder": "log_folder",
    "--eval-freq": "eval_freq",
    "--eval-episodes": "eval_episodes",
    "--checkpoint-freq": "checkpoint_freq",
    "--rig": "rig",
}


def _check_train_extra(algo: str | None) -> None:
    """What training ``algo`` imports (sb3-contrib for its algorithms), or a ValueError naming the extra."""
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401

        if algo in CONTRIB_ALGORITHMS:
            import sb3_contrib  # noqa: F401
    except ImportError:
        raise ValueError(TRAIN_EXTRA) from None


def _cmd_train(args: argparse.Namespace) -> int:
    _check_train_extra(args.algo)
    from microg_env.learning.train import TrainingInterrupted, resolve, resumed_run, train

    given = {field: getattr(args, field) for field in _RUN_FIELDS.values() if getattr(args, field) is not None}
    command = " ".join(["microg", *map(shlex.quote, args.argv)])
    settings = TrainSettings(**given, timesteps=args.timesteps, command=command)
    resume, algo = None, settings.algo
    if args.resume is not None:
        if args.rig is not None:  # its config.yml holds the rig it began on, values and all
            raise ValueError("--resume: a run continues on the rig of its config.yml; leave --rig out")
        resume = Path(args.resume)
        if not (args.resume.strip() and resume.is_dir()):
            raise ValueError(f"--resume {args.resume!r}: no such run folder")
        # A run that cannot go on (its algorithm not installed among them) is named before anything is written.
        _, run, _, _ = resumed_run(resume, settings)
        algo = run.algo
        changed = [
            f"{option} cannot change ({shown(given[field])} asked, {shown(getattr(run, field))} in "
            f"{str(resume / 'args.yml')!r})"
            for option, field in _RUN_FIELDS.items()
            if field in given and given[field] != getattr(run, field)
        ]
        if changed:
            raise ValueError(f"--resume: {'; '.join(changed)}; a run continues with its own args.yml")
    else:
        try:
            resolve(settings)  # a bad file or entry is named before anything is written
        except ValueError as error:
            named = args.hyperparams is not None and not str(error).startswith("--")
            raise ValueError(f"--hyperparams: {error}" if named else str(error)) from None
        check_writable_folder(settings.log_folder, "--log-folder")
    with progress_bar(f"train {algo}", args.quiet) as bar:

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


def _label(text: str) -> tuple[str, str]:
    name, equals, controller = text.partition("=")
    if not (equals and name.strip() and controller.strip()):
        raise argparse.ArgumentTypeError(f"bad label {text!r}: give NAME=CONTROLLER")
    return name.strip(), controller.strip()


def _cmd_compare(args: argparse.Namespace) -> int:
    from microg_env.controllers.registry import check_controller_name
    from microg_env.experiments import comparison, comparison_report

    controllers = args.controllers or list(CONTROLLER_NAMES)
    for name in controllers:
        try:
            check_controller_name(name, args.sensors)
        except ValueError as error:
            raise ValueError(f"--controllers: {error}") from None
    labels = dict(args.label)
    if len(labels) < len(args.label):
        raise ValueError(f"--label: a name is given twice ({', '.join(name for name, _ in args.label)})")
    try:
        comparison.check_labels(labels, controllers)
    except ValueError as error:
        raise ValueError(f"--{error}") from None
    reference = labels.get(args.reference, args.reference)
    if reference is not None and reference not in controllers:
        raise ValueError(f"--reference: must be one of --controllers {','.join(controllers)}, got {args.reference!r}")
    known = comparison_scenarios()
    scenarios = args.scenarios or list(known)
    for name in scenarios:
        if name not in known:
            raise ValueError(f"--scenarios: scenario must be one of {', '.join(known)}, got {name!r}")
    if args.confirmation and args.first_seed is not None:
        raise ValueError(f"--confirmation: runs the seeds from {CONFIRMATION_SEED}; give it or --first-seed, not both")
    first_seed = args.first_seed
    if first_seed is None:
        first_seed = CONFIRMATION_SEED if args.confirmation else TEST_SEED
    last = max(scenario_seeds(name, first_seed, args.seeds)[-1] for name in scenarios)
    if last > MAX_SEED:
        raise ValueError(
            f"--first-seed: {first_seed} with --seeds {args.seeds} runs seed {last} (each scenario its own block of "
            f"{MAX_SEEDS}), above {MAX_SEED}"
        )
    overrides = rig_overrides(args)
    if args.out is not None:
        comparison_report.figure_class()  # fail now, not after the runs, if matplotlib is missing
        comparison_report.check_output(args.out)
    total = (len(controllers) + (len(comparison.FLOORS) if args.floor else 0)) * len(scenarios) * args.seeds
    with progress_bar("compare", args.quiet, total, unit="episode") as bar:
        result = comparison.compare(
            controllers,
            scenarios,
            seeds=args.seeds,
            first_seed=first_seed,
            randomize={None: False, "plant": True}.get(args.randomize, args.randomize),
            duration_s=args.duration,
            reference=reference,
            sensor_set=args.sensors,
            overrides=overrides,
            workers=args.workers,
            progress=bar.update,
            floor=args.floor,
        ).relabelled(labels)
    if args.json:
        print(json.dumps(result.as_dict(), indent=2))
    else:
        print(comparison_report.render_markdown(result))
    if args.out is not None:
        comparison_report.write(result, args.out)
        print(f"wrote {args.out}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _cmd_export_onnx(args: argparse.Namespace) -> int:
    from microg_env.files import check_output_file
    from microg_env.interface import selects_policy
    from microg_env.learning.onnx_export import ONNX_EXTRA, write_onnx

    if importlib.util.find_spec("onnx") is None:
        raise ValueError(ONNX_EXTRA)
    try:
        policy = selects_policy(args.policy)
    except ValueError as error:
        raise ValueError(f"POLICY: {error}") from None
    if not policy:
        raise ValueError(
            f"POLICY {args.policy!r} is a classical baseline, with no network to export; give a shipped policy "
            f"({', '.join(shipped_policies())}) or a policy folder"
        )
    path = check_output_file(args.file, "FILE", (".onnx",))
    write_onnx(args.policy, path)
    print(f"wrote {path}")
    return 0


def add_commands(commands) -> None:
    """train, compare and export-onnx."""
    train = commands.add_parser(
        "train",
        help="train a learned controller with stable-baselines3 (rl-baselines3-zoo layout)",
        description="Train PPO, SAC, TQC or CrossQ on a learning task with the hyperparameters of "
        "microg_env/hyperparams/<algo>.yml (packaged), into logs/<algo>/<env>_<n>/: config, best model, "
        "normalisation, checkpoints, TensorBoard events, monitor files, evaluations by the project's metrics "
        "and the exported policy.",
    )
    defaults = TrainSettings()
    train.add_argument(
        "--algo",
        choices=ALGORITHMS,
        help=f"algorithm: stable-baselines3's PPO or SAC, sb3-contrib's TQC or CrossQ (default {defaults.algo})",
    )
    train.add_argument("--env", dest="env_id", metavar="ENV", help=f"environment id (default {defaults.env_id})")
    train.add_argument(
        "--seed", type=seed_number, help=f"seed of the model and the training environments (default {defaults.seed})"
    )
    train.add_argument("--timesteps", type=count(), metavar="N", help="steps to train (default: the file's)")
    train.add_argument("--n-envs", type=count(MAX_ENVS), metavar="N", help="environments (default: the file's)")
    train.add_argument(
        "-conf",
        "--hyperparams",
        metavar="FILE",
        help="hyperparameter file in rl-baselines3-zoo's format (default: the packaged <algo>.yml)",
    )
    add_rig_option(train)
    train.add_argument("--log-folder", metavar="DIR", help=f"where runs go (default {defaults.log_folder})")
    train.add_argument(
        "--eval-freq", type=count(), metavar="N", help=f"steps between evaluations (default {defaults.eval_freq})"
    )
    train.add_argument(
        "--eval-episodes",
        type=count(MAX_EVAL_EPISODES),
        metavar="N",
        help=f"validation episodes per evaluation (default {defaults.eval_episodes})",
    )
    train.add_argument(
        "--checkpoint-freq",
        type=count(),
        metavar="N",
        help=f"steps between checkpoints (default {defaults.checkpoint_freq})",
    )
    train.add_argument(
        "--resume",
        metavar="RUN",
        help="continue the run in folder RUN from its last checkpoint, with its own settings (to --timesteps)",
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
        help=f"{', '.join(comparison_scenarios())} (default: all)",
    )
    compare.add_argument(
        "--seeds", type=count(MAX_SEEDS), default=5, metavar="N", help="seeds per scenario (default 5)"
    )
    compare.add_argument(
        "--first-seed",
        type=seed_number,
        metavar="S",
        help=f"first seed (default {TEST_SEED}, above training's and validation's); scenario k of the list above "
        f"runs its own seeds from S + k * {MAX_SEEDS}",
    )
    compare.add_argument(
        "--confirmation",
        action="store_true",
        help=f"run the confirmation seeds (from {CONFIRMATION_SEED}): once per release, after every design decision",
    )
    compare.add_argument(
        "--randomize",
        nargs="?",
        const="plant",
        choices=PRESETS,
        help="plants drawn from each seed: the lander, pad, friction and weights (plant, the default), these "
        "and the drive's cogging, motor friction law, speed loop and torque filter (full), or both from ranges "
        "1.5 times wider than training's (wider)",
    )
    compare.add_argument(
        "--sensors",
        choices=("extended", "paper"),
        default="extended",
        help="the rig's sensors: every one (extended, the default) or the paper's (grating ruler and encoder; the "
        "pad force and accelerometer entries read 0)",
    )
    compare.add_argument(
        "--label",
        type=_label,
        action="append",
        default=[],
        metavar="NAME=CONTROLLER",
        help="show CONTROLLER (one of --controllers, e.g. a policy folder) as NAME in tables and figures; repeat",
    )
    compare.add_argument(
        "--reference",
        metavar="NAME",
        help="pair every other controller against this one (ratio with a 95 %% interval resampling seeds, wins, "
        "sign test)",
    )
    compare.add_argument(
        "--no-floor",
        dest="floor",
        action="store_false",
        help="leave out the floor bracket: the oracle on the same episodes with an ideal drive and with no cogging "
        "or friction (default: run it, two rows more)",
    )
    add_duration_option(compare, "cap on each episode's simulated time (default: the scenario's)")
    compare.add_argument(
        "--workers",
        type=count(MAX_WORKERS),
        default=min(usable_cores(), MAX_WORKERS),
        metavar="N",
        help="threads stepping the batch of rigs, processes for the ideal references (default: every usable core)",
    )
    add_rig_option(compare)
    compare.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    compare.add_argument(
        "--out", metavar="DIR", help="also write comparison.md, comparison.json and figures to DIR (replaced)"
    )
    compare.add_argument("--quiet", action="store_true", help="no progress bar")
    compare.set_defaults(handler=_cmd_compare)

    export = commands.add_parser(
        "export-onnx",
        help="export a learned policy's network to ONNX, for a real-time loop",
        description="Write the network of POLICY as an ONNX file: a float64 observation (N, 10) in, a float32 "
        "action (N, 1) out ((N, 3) for a gains policy), equal to the NumPy policy to 1e-6, with how the policy is "
        "deployed (decision period, "
        "hidden entries, residual filter and gate, base controller) in its metadata; docs/deployment.md. Needs "
        "the onnx extra.",
    )
    export.add_argument(
        "policy", metavar="POLICY", help=f"a shipped policy ({', '.join(shipped_policies())}) or a policy folder"
    )
    export.add_argument("file", metavar="FILE", help="the ONNX file to write (.onnx; replaced if it exists)")
    export.set_defaults(handler=_cmd_export_onnx)
