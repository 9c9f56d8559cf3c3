"""``microg train``: stable-baselines3 on a learning task, in rl-baselines3-zoo's layout.

A run lives in ``<log folder>/<algo>/<env id>_<n>/``:

| file | what |
|---|---|
| ``config.yml`` | the resolved hyperparameters, itself a hyperparameter file (``-conf``) |
| ``args.yml`` | the command line and settings of the run |
| ``<env id>.zip``, ``vecnormalize.pkl`` | the final model and normalisation statistics |
| ``best_model.zip``, ``best_vecnormalize.pkl`` | the model with the lowest evaluation cost so far |
| ``policy/`` | the best model exported to NumPy with its card (``microg compare --controllers``) |
| ``checkpoints/`` | ``rl_model_<steps>_steps.zip``, its normalisation (and replay buffer), ``latest.json`` |
| ``checkpoints/best_policy_<steps>_steps/`` | the best model at the last checkpoint, and any since, as ``policy/`` |
| ``evaluations.json`` | every evaluation: steps, wall time, cost, the project's metrics |
| ``train.log`` | progress and evaluations with wall-clock time; the total at the end |
| ``tb/`` | TensorBoard events (the algorithm's and ``eval/``) |
| ``monitor/`` | stable-baselines3's monitor file of each session (episode return, length, time) |

Evaluation uses the project's metrics, not only the return: every ``eval_freq`` steps the
deterministic policy runs, as a :class:`~microg_env.controllers.policy.PolicyController` in the
speed-action environment (exactly as it will be deployed), on ``eval_episodes`` validation
schedules (:data:`~microg_env.scenarios.VALIDATION_SAMPLER`, longer than the training draws) with
the training run's imperfections and randomisation, seeds from :data:`VALIDATION_SEED` (never a
training or test seed); the cost is :func:`~microg_env.analysis.summary.selection_cost`, the PID
tuner's with the mean excursion at the collision in place of the worst. A model evaluated before
its first update (an off-policy algorithm before ``learning_starts``) is recorded but never the
best: it has learned nothing. PPO's policy changes only between rollouts, after the rollout's last
step: its evaluation falls at the start of the rollout after the step it was due at, or at the
run's end, so that it sees the update. Every file is written atomically; ``latest.json`` is written after its
checkpoint's files, so ``--resume`` always finds a complete one, and continues the step count, the
normalisation statistics, the replay buffer, the best cost, the evaluation history and the
wall-clock total. A session stopped after its last checkpoint
(killed) left evaluations, and maybe a best model, of steps a resume trains again: the resume drops
them and puts back the best model of the evaluations it keeps, so every record is of one timeline.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import time
import zipfile
from collections.abc import Callable
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from microg_env.controllers.registry import deployed_controller, make_controller
from microg_env.files import atomic_path, folder_lock, read_settings_text, read_yaml, replace_folder, write_text
from microg_env.interface import CARD_FILE
from microg_env.learning import hyperparams as hp
from microg_env.learning.export import MODEL_FILE, NORMALIZATION_FILE, write_policy_folder
from microg_env.learning.settings import (
    ALGORITHMS,
    CONTRIB_ALGORITHMS,
    ENV_IDS,
    MAX_ENVS,
    MAX_EVAL_EPISODES,
    TRAIN_EXTRA,
    TrainSettings,
)
from microg_env.params import CONTROL_PERIOD_S, RigParams
from microg_env.rigs import read_rig_option
from microg_env.task import ACTING_KEYS, ActingSettings, TaskSettings
from microg_env.validate import fault, shown

#: First seed of the validation episodes that choose the best model (training envs are seeded
#: ``seed`` to ``seed + n_envs - 1``; ``microg compare`` tests on seeds from 1000).
VALIDATION_SEED = 500
#: Folders and files of a run.
CHECKPOINTS, LATEST, POLICY, EVALUATIONS, LOG = "checkpoints", "latest.json", "policy", "evaluations.json", "train.log"


class TrainingInterrupted(Exception):
    """Training stopped by the user after saving a checkpoint."""


#: The integer settings of a run (``args.yml``) and their ranges.
SETTING_RANGES = {
    "seed": (0, 2**32 - 1),
    "timesteps": (1, 10**12),
    "n_envs": (1, MAX_ENVS),
    "eval_freq": (1, 10**12),
    "eval_episodes": (1, MAX_EVAL_EPISODES),
    "checkpoint_freq": (1, 10**12),
}


def algorithm(name: str):
    """The algorithm class of ``name`` (one of :data:`~microg_env.learning.settings.ALGORITHMS`);
    TQC (truncated quantile critics, an actor built as SAC's) and CrossQ (SAC with batch
    renormalisation and no target networks) are sb3-contrib's, imported only for them (a ValueError
    naming the extra where it is missing)."""
    if name in CONTRIB_ALGORITHMS:
        try:
            import sb3_contrib
        except ImportError:
            raise ValueError(TRAIN_EXTRA) from None

        return getattr(sb3_contrib, CONTRIB_ALGORITHMS[name])
    from stable_baselines3 import PPO, SAC

    return {"ppo": PPO, "sac": SAC}[name]


def session_seed(seed: int, steps_done: int) -> int:
    """The first training environment's seed in a session that starts after ``steps_done`` steps:
    the run's seed, then seeds drawn from (seed, steps), at least 2^20: never a validation or test seed."""
    if steps_done == 0:
        return seed
    return int(np.random.SeedSequence([seed, steps_done]).generate_state(1)[0]) | 1 << 20


def new_run_folder(log_folder: str | Path, algo: str, env_id: str) -> Path:
    """``<log folder>/<algo>/<env id>_<n>`` with n one more than the highest there (the zoo's rule)."""
    parent = Path(log_folder) / algo
    parent.mkdir(parents=True, exist_ok=True)
    taken = [p.name.removeprefix(f"{env_id}_") for p in parent.glob(f"{env_id}_*")]
    number = max((int(n) for n in taken if n.isdigit()), default=0) + 1
    while True:
        folder = parent / f"{env_id}_{number}"
        try:
            folder.mkdir()
            return folder
        except FileExistsError:  # another run took it
            number += 1


def train(
    settings: TrainSettings,
    resume_folder: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> Path:
    """Train (or continue the run in ``resume_folder``); returns the run folder.

    ``progress(steps_done, steps_total)`` follows the steps; ``log(line)`` gets every line of
    ``train.log`` as it is written. Ctrl-C saves a checkpoint and raises :class:`TrainingInterrupted`.
    """
    import torch
    import yaml

    torch.set_num_threads(1)  # small networks: one thread is fastest on a shared machine
    if resume_folder is not None and not Path(resume_folder).is_dir():
        raise ValueError(f"--resume {str(resume_folder)!r}: no such run folder")
    params = resolve(settings) if resume_folder is None else None
    folder = (
        Path(resume_folder) if params is None else new_run_folder(settings.log_folder, settings.algo, settings.env_id)
    )
    try:
        with folder_lock(folder, "run folder"):  # one process writes a run folder at a time
            if params is not None:
                write_text(
                    folder / "config.yml", yaml.safe_dump({settings.env_id: params.as_config()}, sort_keys=False)
                )
                state = {"timesteps": 0, "wall_s": 0.0, "best_cost": None, "sessions": 0, "resume_commands": []}
            else:
                folder, settings, params, state = resumed_run(folder, settings)
            # the run's settings as run: n_envs resolved (not null), a resume's new target
            recorded = replace(settings, n_envs=params.n_envs)
            write_text(folder / "args.yml", yaml.safe_dump(asdict(recorded), sort_keys=False))
            return _Run(folder, settings, params, state, progress, log).learn()
    except KeyboardInterrupt:  # before the training loop took it over (building, the base's evaluation)
        if resume_folder is None and not (folder / CHECKPOINTS / LATEST).exists():
            shutil.rmtree(folder, ignore_errors=True)  # nothing to resume: no orphan run folder
            raise TrainingInterrupted("interrupted before the first checkpoint; nothing was kept") from None
        raise TrainingInterrupted(f"interrupted; continue with: microg train --resume {folder}") from None


def resolve(settings: TrainSettings) -> hp.Hyperparams:
    """The run's hyperparameters: the file's entry for the env with the settings' overrides."""
    if settings.env_id not in ENV_IDS:
        raise ValueError(f"--env must be one of {', '.join(ENV_IDS)}, got {settings.env_id!r}")
    params = hp.load(settings.algo, settings.env_id, settings.hyperparams)
    if settings.timesteps is not None:
        params = replace(params, n_timesteps=settings.timesteps)
    if settings.n_envs is not None:
        params = replace(params, n_envs=settings.n_envs)
    if settings.rig is not None:  # on the entry's own rig parameters, if any
        rig = read_rig_option(settings.rig, "--rig").overrides
        entry = params.env_kwargs.get("params") or {}
        params = replace(params, env_kwargs=params.env_kwargs | {"params": dict(entry) | rig})
    check_entry(params)
    return params


def check_entry(params: hp.Hyperparams) -> None:
    """The entry's env_kwargs make the environment, its other keys are the algorithm's keyword
    arguments, and the model they build exports as the run's policy will be exported: checked before
    a run folder is made, so a bad file is named with its key and nothing is written."""
    import inspect

    import gymnasium as gym

    where = f"{Path(params.source).name}[{params.env_id}]"
    try:
        gym.make(params.env_id, **params.env_kwargs).close()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{where}.env_kwargs: {error}") from None
    accepted = inspect.signature(algorithm(params.algo)).parameters
    unknown = [key for key in params.algo_kwargs if key not in accepted or key in ("env", "policy")]
    if unknown:
        raise ValueError(f"{where}: {', '.join(map(repr, unknown))} is not an argument of {params.algo.upper()}")
    from microg_env.learning.vec_env import BatchedVecEnv

    # The model and its normalisation built on the run's environments (a batch of rigs is cheap to
    # make): what they or the export refuse, they refuse now, named by its key.
    venv = BatchedVecEnv.make(params.n_envs, **params.env_kwargs)
    try:
        refusal = _deployment_fault(params, venv)
        if refusal is not None:
            key = _blamed_key(params, venv, refusal)
            raise ValueError(f"{where}{'' if key is None else f'.{key}'}: {refusal}")
    finally:
        venv.close()


def _blamed_key(params: hp.Hyperparams, venv, refusal: str) -> str | None:
    """The key of the entry that, left out, makes it pass (the innermost first); else the first
    whose leaving out ends this refusal (the entry has another fault too); None if none does."""
    changed = None
    for key in _entry_keys(params):
        without = _deployment_fault(_without(params, key), venv)
        if without is None:
            return key
        if changed is None and without != refusal:
            changed = key
    return changed


def _deployment_fault(params: hp.Hyperparams, venv) -> str | None:
    """Why the model of ``params`` cannot be built on ``venv``, or its untrained actor cannot be
    exported as the run's best will be (:func:`~microg_env.learning.export.export_policy`); None if
    it can. Their warnings come when the run starts."""
    import warnings

    from stable_baselines3.common.vec_env import VecNormalize

    from microg_env.learning.export import export_policy

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            normalized = venv if params.normalize is None else VecNormalize(venv, **params.normalize)
            model = algorithm(params.algo)(params.policy, normalized, device="cpu", **hp.algo_arguments(params))
        except (TypeError, ValueError, AssertionError, KeyError, AttributeError, RuntimeError) as error:
            return f"{params.algo.upper()} refuses it: {fault(error)}"
    try:
        export_policy(model, model.get_vec_normalize_env())
    except ValueError as error:
        return f"its policy cannot be exported: {fault(error)}"
    return None


def _entry_keys(params: hp.Hyperparams) -> list[str]:
    """The keys of an entry a refusal may be blamed on, innermost first: policy_kwargs' and
    normalize's own, then the algorithm's arguments and normalize."""
    inner = [f"policy_kwargs.{key}" for key in params.algo_kwargs.get("policy_kwargs") or {}]
    inner += [f"normalize.{key}" for key in params.normalize or {}]
    return [*inner, *params.algo_kwargs, *([] if params.normalize is None else ["normalize"])]


def _without(params: hp.Hyperparams, key: str) -> hp.Hyperparams:
    """``params`` with ``key`` (one of :func:`_entry_keys`) left out: at its default."""
    group, _, name = key.partition(".")
    if group == "normalize":
        normalize = None if not name else {k: v for k, v in params.normalize.items() if k != name}
        return replace(params, normalize=normalize)
    kwargs = dict(params.algo_kwargs)
    if name:
        kwargs[group] = {k: v for k, v in kwargs[group].items() if k != name}
    else:
        del kwargs[group]
    return replace(params, algo_kwargs=kwargs)


def resumed_run(folder: Path, asked: TrainSettings) -> tuple[Path, TrainSettings, hp.Hyperparams, dict[str, Any]]:
    """The run in ``folder`` as it was left, with a new step target if one is asked."""
    latest = folder / CHECKPOINTS / LATEST
    if not latest.is_file():
        raise ValueError(f"--resume {str(folder)!r}: no checkpoint to resume from ({latest} is missing)")
    args = read_yaml(folder / "args.yml", "run file")
    try:
        state = json.loads(read_settings_text(latest, "checkpoint record"))
    except json.JSONDecodeError as error:
        raise ValueError(f"--resume {str(folder)!r}: cannot read the run ({fault(error)})") from None
    settings = _check_args(folder / "args.yml", args)
    _check_state(folder / CHECKPOINTS, state)
    _check_algorithm(folder / "args.yml", settings.algo, folder / CHECKPOINTS / state["model"])
    _check_evaluations(folder / EVALUATIONS)
    params = hp.load(settings.algo, settings.env_id, folder / "config.yml")
    target = asked.timesteps if asked.timesteps is not None else settings.timesteps  # args.yml keeps the last
    if target is not None:
        params = replace(params, n_timesteps=target)
        settings = replace(settings, timesteps=target)
    if params.n_timesteps <= state["timesteps"] and state.get("finished", True):
        raise ValueError(
            f"--timesteps {params.n_timesteps}: the run in {str(folder)!r} already has {state['timesteps']} steps; "
            "ask for more"
        )
    if asked.command:
        state["resume_commands"] = [*state.get("resume_commands", []), asked.command]
    return folder, settings, params, state


def _check_args(path: Path, args: object) -> TrainSettings:
    """The settings an ``args.yml`` records, or a ValueError naming the file and the fault."""
    names = {f.name for f in fields(TrainSettings)}
    if not isinstance(args, dict) or not args or set(args) - names:
        unknown = sorted(map(str, set(args) - names)) if isinstance(args, dict) else []
        why = f"unknown keys {', '.join(unknown)}" if unknown else "not a mapping of the run's settings"
        raise ValueError(f"--resume: {str(path)!r}: {why}")
    where = f"--resume: {str(path)!r}"
    settings = TrainSettings(**args)
    for name, choices in (("algo", ALGORITHMS), ("env_id", ENV_IDS)):
        value = getattr(settings, name)
        if value not in choices:
            raise ValueError(f"{where}: {name} must be one of {', '.join(choices)}, got {shown(value)}")
    for name, (low, high) in SETTING_RANGES.items():
        value = getattr(settings, name)
        if value is None and name in ("timesteps", "n_envs"):
            continue  # the hyperparameter file's
        if type(value) is not int or not low <= value <= high:
            raise ValueError(f"{where}: {name} must be an integer in [{low}, {high}], got {shown(value)}")
    for name in ("hyperparams", "log_folder", "command"):
        value = getattr(settings, name)
        if not isinstance(value, str) and not (value is None and name == "hyperparams"):
            raise ValueError(f"{where}: {name} must be text, got {shown(value)}")
    return settings


def _check_state(checkpoints: Path, state: object) -> None:
    """A ``latest.json`` of the right kinds, naming only files inside ``checkpoints`` that exist
    (a path out of the run folder is never followed); else a ValueError naming it."""
    where = f"--resume: {str(checkpoints / LATEST)!r}"
    if not isinstance(state, dict):
        raise ValueError(f"{where}: not a checkpoint record (a JSON object)")
    kinds = {"timesteps": int, "sessions": int, "wall_s": (int, float), "model": str}
    for key, kind in kinds.items():
        value = state.get(key)
        low = 1 if key == "timesteps" else 0  # a checkpoint is written after some steps
        if not isinstance(value, kind) or isinstance(value, bool) or (kind is int and value < low):
            raise ValueError(f"{where}: {key} must be a {'file name' if kind is str else 'number'}, got {shown(value)}")
    for key in ("best_cost", "base_cost"):  # null: not evaluated yet
        value = state.get(key)
        if value is not None and not (isinstance(value, int | float) and not isinstance(value, bool) and value >= 0):
            raise ValueError(f"{where}: {key} must be a cost (a number of at least 0) or null, got {shown(value)}")
    if not isinstance(state.get("finished", True), bool):
        raise ValueError(f"{where}: finished must be true or false, got {shown(state['finished'])}")
    commands = state.get("resume_commands", [])
    if not (isinstance(commands, list) and all(isinstance(c, str) for c in commands)):
        raise ValueError(f"{where}: resume_commands must be a list of commands, got {shown(commands)}")
    for key in ("model", "vecnormalize", "replay_buffer"):
        name = state.get(key)
        if key != "model" and name is None:
            continue
        if not isinstance(name, str) or Path(name).name != name or name in ("", ".", ".."):
            raise ValueError(f"{where}: {key} must name a file in {str(checkpoints)!r}, got {shown(name)}")
        if not (checkpoints / name).is_file() or (checkpoints / name).stat().st_size == 0:
            raise ValueError(f"{where}: its {key} {str(checkpoints / name)!r} is missing or empty")
    normalization = state.get("vecnormalize")
    _check_checkpoint(where, checkpoints / state["model"], normalization and checkpoints / normalization)


def _check_evaluations(path: Path) -> None:
    """A run's ``evaluations.json`` (absent: none yet) is a list of rows each scored as this version
    scores (:func:`~microg_env.analysis.summary.selection_cost`: |compensation error| [%] + the mean
    x at the collision [um] / 10, both in the row): a run scored by the worst x at the collision
    (before 0.12.0) would compare its old best with costs of another rule. Else a ValueError."""
    where = f"--resume: {str(path)!r}"
    try:
        rows = _read_json(path, [])
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{where}: cannot read the run's evaluations ({fault(error)})") from None
    if not (isinstance(rows, list) and all(isinstance(row, dict) and "cost" in row for row in rows)):
        raise ValueError(f"{where}: not a list of evaluations (JSON objects, each with a cost)")
    steps = [row.get("timesteps") for row in rows]
    if not all(type(step) is int and step >= 1 for step in steps):
        raise ValueError(f"{where}: every evaluation must give its timesteps (a positive integer), got {shown(steps)}")
    for row in rows:
        figures = [row.get(key) for key in ("cost", "compensation_error_pct", "collision_excursion_um")]
        if not all(isinstance(value, int | float) and not isinstance(value, bool) for value in figures):
            continue  # a failed evaluation (null figures) sets no best
        cost, error, collision = figures
        if not math.isclose(cost, error + collision / 10, rel_tol=1e-6, abs_tol=1e-12):
            raise ValueError(
                f"{where}: the evaluation at {shown(row.get('timesteps'))} steps costs {cost!r}, not "
                f"|compensation error| + x at the collision / 10 um ({error + collision / 10:.6g}): "
                "a run scored by the worst x at the collision (before 0.12.0) cannot be resumed; start a new run"
            )


def _check_algorithm(args: Path, algo: str, model: Path) -> None:
    """The checkpoint's model is one of ``algo``'s, the algorithm ``args`` names (stable-baselines3
    records its policy class in the archive): else a ValueError naming both, not an AttributeError
    deep in loading one algorithm's model as another's."""
    with zipfile.ZipFile(model) as archive:  # a whole archive holding its data (_check_checkpoint)
        try:
            module = json.loads(archive.read("data"))["policy_class"]["__module__"]
        except (ValueError, KeyError, TypeError):
            module = None
    if module in _policy_modules(algo):
        return
    holds = f"no {algo.upper()} model"
    for name in ALGORITHMS:
        try:
            if module in _policy_modules(name):
                holds = f"a {name.upper()} model"
        except ValueError:
            continue  # not installed: not what the checkpoint was trained with here
    raise ValueError(f"--resume: {str(args)!r} names algo {algo}, but its checkpoint {str(model)!r} holds {holds}")


def _policy_modules(algo: str) -> set[str]:
    """The modules of ``algo``'s policy classes."""
    return {policy.__module__ for policy in algorithm(algo).policy_aliases.values()}


def _check_checkpoint(where: str, model: Path, normalization: Path | None) -> None:
    """The model a checkpoint names is a stable-baselines3 archive (a zip holding its data), and its
    normalisation unpickles to VecNormalize's statistics; else a ValueError naming the file, before
    the resume opens anything (the folder must be trusted: these are pickles)."""
    import pickle

    from stable_baselines3.common.vec_env import VecNormalize

    try:
        with zipfile.ZipFile(model) as archive:
            readable = "data" in archive.namelist() and archive.testzip() is None
    except (zipfile.BadZipFile, OSError):
        readable = False
    if not readable:
        raise ValueError(f"{where}: its model {str(model)!r} is not a whole stable-baselines3 archive")
    if normalization is None:
        return
    try:
        with open(normalization, "rb") as stream:
            statistics = pickle.load(stream)  # a trusted run folder, as docs/cli.md says
    except Exception as error:  # a damaged pickle raises any of a dozen kinds
        kind = type(error).__name__
        raise ValueError(f"{where}: its vecnormalize {str(normalization)!r} cannot be read ({kind})") from None
    if not isinstance(statistics, VecNormalize):
        raise ValueError(f"{where}: its vecnormalize {str(normalization)!r} holds no VecNormalize statistics")


class _Run:
    """One training session of a run folder: environments, model, callbacks."""

    def __init__(self, folder, settings, params, state, progress, log) -> None:
        self.folder, self.settings, self.params, self.state = folder, settings, params, state
        self.progress, self.echo = progress, log
        self.session_start, self.earlier_wall_s = time.monotonic(), state["wall_s"]
        self.evaluations = _read_json(folder / EVALUATIONS, [])
        if state["timesteps"] > 0:
            self.rewind()
        # The best model on disk is the best of the evaluations (those up to the checkpoint, after rewind).
        costs = [row["cost"] for row in self.evaluations if row.get("best") and row["cost"] is not None]
        self.state["best_cost"] = min(costs, default=None)

    def rewind(self) -> None:
        """Back to the checkpoint resumed from. Evaluations after it, and a best model saved after
        it, are of a session stopped before its next checkpoint, whose steps this session trains
        again: they are dropped, and the best model of the evaluations kept is put back from its
        copy in ``checkpoints/``. Where there is none (a run of 0.16.0 or earlier), no evaluation kept
        is marked best any more, for none of their models is on disk: the next one is the best."""
        steps = self.state["timesteps"]
        kept = [row for row in self.evaluations if row["timesteps"] <= steps]
        best = _best_steps(kept)
        saved = _saved_steps(self.folder / POLICY)
        note = []
        if len(kept) < len(self.evaluations):
            note.append(f"{len(self.evaluations) - len(kept)} evaluation(s) after it dropped")
        if saved != best:
            copy = None if best is None else self.folder / CHECKPOINTS / _best_copy(best)
            if copy is not None and copy.is_dir():
                self.install_best(copy)
                note.append(f"the best model of step {saved} replaced by step {best}'s")
            else:
                for name in ("best_model.zip", "best_vecnormalize.pkl"):
                    (self.folder / name).unlink(missing_ok=True)
                shutil.rmtree(self.folder / POLICY, ignore_errors=True)
                kept = [row | {"best": False} for row in kept]
                note.append(f"the best model of step {saved} removed, and no model of an evaluation kept is on disk")
                best = None
        _keep_best_copy(self.folder / CHECKPOINTS, best)
        if note:
            self.evaluations = kept
            write_text(self.folder / EVALUATIONS, json.dumps(self.evaluations, indent=1) + "\n")
            self.log(f"back to the checkpoint at {steps} steps: {'; '.join(note)}")

    # -- the log ---------------------------------------------------------------------------

    def log(self, text: str) -> None:
        line = f"[{self.wall_s():8.1f} s] {text}"
        with open(self.folder / LOG, "a", encoding="utf-8") as stream:
            stream.write(line + "\n")
        if self.echo is not None:
            self.echo(line)

    def wall_s(self) -> float:
        """Wall-clock time of the whole run, every session."""
        return self.earlier_wall_s + time.monotonic() - self.session_start

    # -- building --------------------------------------------------------------------------

    def _environments(self, resuming: bool):
        from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

        from microg_env.learning.vec_env import BatchedVecEnv

        # Every rig on one mujoco.batch; one monitor file per session, session-<n>.monitor.csv.
        venv = BatchedVecEnv.make(self.params.n_envs, **self.params.env_kwargs)
        folder = self.folder / "monitor"
        folder.mkdir(exist_ok=True)
        session = len(list(folder.glob("session-*.monitor.csv")))
        venv = VecMonitor(venv, filename=str(folder / f"session-{session}"), info_keywords=("termination_reason",))
        if self.params.normalize is None:
            return venv
        if resuming:
            statistics = VecNormalize.load(str(self.folder / CHECKPOINTS / self.state["vecnormalize"]), venv)
            statistics.training = True
            return statistics
        return VecNormalize(venv, **self.params.normalize)

    def _model(self, venv, resuming: bool):
        cls = algorithm(self.params.algo)
        seed = self.settings.seed + self.state["timesteps"]
        if not resuming:
            return cls(
                self.params.policy,
                venv,
                seed=seed,
                device="cpu",
                tensorboard_log=str(self.folder / "tb"),
                verbose=0,
                **hp.algo_arguments(self.params),
            )
        checkpoints = self.folder / CHECKPOINTS
        model = cls.load(
            checkpoints / self.state["model"], env=venv, device="cpu", tensorboard_log=str(self.folder / "tb")
        )
        model.set_random_seed(seed)
        if self.state.get("replay_buffer"):
            model.load_replay_buffer(checkpoints / self.state["replay_buffer"])
        return model

    # -- training --------------------------------------------------------------------------

    def learn(self) -> Path:
        from stable_baselines3.common.callbacks import CallbackList

        resuming = self.state["timesteps"] > 0
        self.state["sessions"] += 1
        self.state["finished"] = False  # until the final evaluation and export are on disk
        # Envs are seeded seed..seed+n-1; a resumed session draws fresh seeds from (seed, steps run),
        # far from the validation (500+) and test (1000+) seeds.
        env_seed = session_seed(self.settings.seed, self.state["timesteps"])
        venv = self._environments(resuming)
        model = self._model(venv, resuming)
        venv.seed(env_seed)  # after the model, whose set_random_seed would seed the envs with its own seed
        target = self.params.n_timesteps
        self.planned = planned_steps(self.params, model.num_timesteps)
        whole = f" (runs to {self.planned}: whole rollouts)" if self.planned not in (None, target) else ""
        command = (self.state.get("resume_commands") or [""])[-1] if resuming else self.settings.command
        self.log(
            f"{'resumed at' if resuming else 'started'} {model.num_timesteps} steps: {self.params.algo} on "
            f"{self.params.env_id}, {self.params.n_envs} envs, target {target} steps{whole}, seed "
            f"{self.settings.seed}; {command}"
        )
        self.base_cost()
        callbacks = CallbackList([_callback(self)])
        start = model.num_timesteps
        try:  # no steps left: a session that finishes a run stopped after its last step (sets up the logger)
            model.learn(
                max(target - model.num_timesteps, 0),
                callback=callbacks,
                reset_num_timesteps=False,
                tb_log_name=self.params.algo,
                log_interval=1 if self.params.algo == "ppo" else 10,
            )
        except KeyboardInterrupt:
            self._stop(model, venv, start)
        if model.num_timesteps > start:  # after the last step's transition is stored (a callback's is before)
            self.checkpoint(model)
        try:  # the last model evaluated (and exported if best), whichever session trained it
            if not self.evaluations or self.evaluations[-1]["timesteps"] < model.num_timesteps:
                self.evaluate(model)
            with atomic_path(self.folder / f"{self.params.env_id}.zip") as temporary:
                model.save(temporary)
            normalization = model.get_vec_normalize_env()
            if normalization is not None:
                with atomic_path(self.folder / "vecnormalize.pkl") as temporary:
                    normalization.save(str(temporary))
        except KeyboardInterrupt:
            self._stop(model, venv, model.num_timesteps)  # checkpointed above
        venv.close()
        self.state["finished"] = True
        self.state["wall_s"] = round(self.wall_s(), 1)  # the final evaluation and export included
        write_text(self.folder / CHECKPOINTS / LATEST, json.dumps(self.state, indent=2) + "\n")
        best, base = self.state["best_cost"], self.state.get("base_cost")
        verdict = ""
        if best is not None and base is not None:
            verdict = "; it beats" if best < base else "; it does NOT beat"
            verdict += f" {self._line_to_beat()[1]} ({base:.4g})"
        if best is None:
            why = (
                "the run ended before its first update"
                if not getattr(model, "_n_updates", 1)
                else "every evaluation failed"
            )
            best = f"none ({why})"
        else:
            best = f"{best:.4g}"
        self.log(
            f"finished: {model.num_timesteps} steps in {self.wall_s():.1f} s wall over "
            f"{self.state['sessions']} session(s); best evaluation cost {best}{verdict}"
        )
        return self.folder

    def _stop(self, model, venv, start: int) -> None:
        """Ctrl-C: the run as it is, checkpointed if this session stepped since ``start``, and how to go on."""
        if model.num_timesteps > start:
            self.checkpoint(model)
        venv.close()
        self.log(f"interrupted at {model.num_timesteps} steps; continue with: microg train --resume {self.folder}")
        raise TrainingInterrupted(f"interrupted; continue with: microg train --resume {self.folder}")

    def checkpoint(self, model) -> None:
        """Save model, normalisation and replay buffer, then point ``latest.json`` at them."""
        folder = self.folder / CHECKPOINTS
        folder.mkdir(exist_ok=True)
        steps = model.num_timesteps
        files = {"model": f"rl_model_{steps}_steps.zip"}
        with atomic_path(folder / files["model"]) as temporary:
            model.save(temporary)
        normalization = model.get_vec_normalize_env()
        if normalization is not None:
            files["vecnormalize"] = f"rl_model_vecnormalize_{steps}_steps.pkl"
            with atomic_path(folder / files["vecnormalize"]) as temporary:
                normalization.save(str(temporary))
        if hasattr(model, "replay_buffer") and model.replay_buffer is not None:
            files["replay_buffer"] = f"rl_model_replay_buffer_{steps}_steps.pkl"
            with atomic_path(folder / files["replay_buffer"]) as temporary:
                model.save_replay_buffer(temporary)
        previous_buffer = self.state.get("replay_buffer")
        self.state = self.state | files | {"timesteps": steps, "wall_s": round(self.wall_s(), 1)}
        write_text(folder / LATEST, json.dumps(self.state, indent=2) + "\n")
        if previous_buffer and previous_buffer != files.get("replay_buffer"):
            (folder / previous_buffer).unlink(missing_ok=True)  # one replay buffer is enough (and large)
        _keep_best_copy(folder, _best_steps(self.evaluations))  # a resume goes back no further

    def rig(self) -> RigParams:
        """The nominal rig trained on (the entry's ``params``): what a base controller assumes."""
        return TaskSettings(**self.params.env_kwargs).params

    def validate(self, controller) -> tuple[list, float, float]:
        """The runs, failure rate and cost of ``controller`` on the validation schedules, the
        episodes the rigs of one batch."""
        from microg_env.analysis.summary import selection_cost

        runs, failure_rate = validation_runs(self.params.env_kwargs, controller, self.settings.eval_episodes)
        return runs, failure_rate, selection_cost(runs)

    def base_cost(self) -> None:
        """A policy's line to beat on the validation schedules, once per run, logged and kept in
        ``latest.json``: a residual or gains policy's base controller alone (a zero action); a speed
        policy's, the paper's PID."""
        if "base_cost" in self.state:
            return
        base, what = self._line_to_beat()
        period = float(self.params.env_kwargs.get("control_period_s", CONTROL_PERIOD_S))
        *_, cost = self.validate(make_controller(base, period, self.rig()))  # what a zero action leaves it
        self.state["base_cost"] = _json_number(cost)
        detail = "" if self._speed_policy() else f" ({base}, a zero action)"
        self.log(f"{what}{detail}: cost {_show(cost, '.4g')}, the line to beat")

    def _speed_policy(self) -> bool:
        """Whether the run's policy commands the drive's speed itself (no base controller)."""
        return ActingSettings.of(self.params.env_kwargs).action_mode == "speed"

    def _line_to_beat(self) -> tuple[str, str]:
        """The controller a run's policy is to beat, and what the log calls it."""
        if self._speed_policy():
            return "pid", "the paper's PID"
        return self.params.env_kwargs.get("base_controller", "pid"), "the base controller alone"

    def evaluate(self, model) -> None:
        """The deterministic policy on the validation schedules, by the project's metrics."""
        from microg_env.analysis.summary import finite_mean

        normalization = model.get_vec_normalize_env()
        policy = NormalizedPolicy(model, normalization)
        runs, failure_rate, cost = self.validate(deployed_controller(policy, self.params.env_kwargs, params=self.rig()))
        row = {
            "timesteps": model.num_timesteps,
            "wall_s": round(self.wall_s(), 1),
            "cost": cost,
            "compensation_error_pct": finite_mean(abs(e) for run in runs for e in run.compensation_error_pct),
            "free_fall_excursion_um": finite_mean(run.flexible_unit_excursion_free_fall_m * 1e6 for run in runs),
            "collision_excursion_um": finite_mean(run.flexible_unit_excursion_collision_m * 1e6 for run in runs),
            "failure_rate": failure_rate,
        }
        for key, value in row.items():
            if key not in ("timesteps", "wall_s"):
                model.logger.record(f"eval/{key}", value)
        if self.state.get("base_cost") is not None:  # the line to beat, beside the cost in TensorBoard
            model.logger.record("eval/base_cost", self.state["base_cost"])
        model.logger.dump(model.num_timesteps)
        best, learned = self.state["best_cost"], getattr(model, "_n_updates", 1) > 0
        new_best = learned and math.isfinite(cost) and (best is None or cost < best)
        row = {key: _json_number(value) for key, value in row.items()} | {"best": new_best}
        if new_best:  # saved before it is recorded: a best in evaluations.json is always on disk
            self.save_best(model, row)
            self.state["best_cost"] = cost
        self.evaluations.append(row)
        write_text(self.folder / EVALUATIONS, json.dumps(self.evaluations, indent=1) + "\n")
        self.log(
            f"eval at {row['timesteps']} steps: cost {_show(cost, '.4g')}, "
            f"|compensation error| {_show(row['compensation_error_pct'], '.4f')} %, "
            f"x free fall {_show(row['free_fall_excursion_um'], '.3f')} um, "
            f"collision {_show(row['collision_excursion_um'], '.3f')} um, failures {failure_rate:.0%}"
            + (" (new best)" if new_best else "" if learned else " (before its first update: never the best)")
        )

    def save_best(self, model, row: dict[str, Any]) -> None:
        """The new best model, exported with its card into ``checkpoints/`` (kept until a checkpoint
        passes a later best: a resume from an earlier checkpoint puts it back), then made the run's."""
        copy = self.folder / CHECKPOINTS / _best_copy(row["timesteps"])
        copy.parent.mkdir(exist_ok=True)
        write_policy_folder(copy, model, model.get_vec_normalize_env(), self.card(model, row))
        self.install_best(copy)

    def install_best(self, copy: Path) -> None:
        """The best model kept in ``copy`` made the run's: best_model.zip, best_vecnormalize.pkl, policy/."""
        for name, target in ((MODEL_FILE, "best_model.zip"), (NORMALIZATION_FILE, "best_vecnormalize.pkl")):
            if (copy / name).is_file():
                with atomic_path(self.folder / target) as temporary:
                    shutil.copyfile(copy / name, temporary)

        def fill(staging: Path) -> None:
            for path in copy.iterdir():
                if not path.name.startswith("."):  # not a swap's marker
                    shutil.copyfile(path, staging / path.name)

        replace_folder(self.folder / POLICY, fill)

    def card(self, model, row: dict[str, Any]) -> dict[str, Any]:
        """The policy's provenance: how it acts, the exact command and seed that trained it, its budget."""
        import stable_baselines3
        import torch

        from microg_env.version import __version__

        versions = {"microg_env": __version__, "stable_baselines3": stable_baselines3.__version__}
        if self.params.algo in CONTRIB_ALGORITHMS:
            import sb3_contrib

            versions["sb3_contrib"] = sb3_contrib.__version__
        return {
            "env_id": self.params.env_id,
            "env_kwargs": self.params.env_kwargs,
            "algo": self.params.algo,
            "command": self.settings.command,
            "resume_commands": self.state.get("resume_commands", []),
            "seed": self.settings.seed,
            "timesteps": model.num_timesteps,
            "target_timesteps": self.params.n_timesteps,
            "wall_s": round(self.wall_s(), 1),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, torch {torch.get_num_threads()} thread(s)",
            "hyperparams": self.params.as_config(),
            "validation": row | {"seeds": [VALIDATION_SEED, VALIDATION_SEED + self.settings.eval_episodes - 1]},
            "versions": versions | {"torch": torch.__version__, "numpy": np.__version__},
        }


def _callback(run: _Run):
    """Evaluation, checkpoints and progress, at the frequencies of the settings (in total steps)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Callback(BaseCallback):
        def _on_training_start(self) -> None:
            self.next_eval = _next_multiple(self.num_timesteps, run.settings.eval_freq)
            self.next_checkpoint = _next_multiple(self.num_timesteps, run.settings.checkpoint_freq)
            self.between_rollouts = run.params.algo == "ppo"  # PPO updates after a rollout's last step

        def _evaluate_if_due(self) -> None:
            if self.num_timesteps >= self.next_eval:
                run.evaluate(self.model)
                self.next_eval = _next_multiple(self.num_timesteps, run.settings.eval_freq)

        def _on_rollout_start(self) -> None:
            if self.between_rollouts:
                self._evaluate_if_due()

        def _on_step(self) -> bool:
            steps = self.num_timesteps
            if run.progress is not None:
                run.progress(steps, max(run.planned or run.params.n_timesteps, steps))
            if not self.between_rollouts:
                self._evaluate_if_due()
            if steps >= self.next_checkpoint:
                run.checkpoint(self.model)
                self.next_checkpoint = _next_multiple(steps, run.settings.checkpoint_freq)
            return True

    return Callback()


def planned_steps(params: hp.Hyperparams, start: int) -> int | None:
    """The step count stable-baselines3's ``learn`` stops at from ``start``: the first at or past the
    target that ends a whole rollout, n_envs x n_steps (PPO) or n_envs x train_freq steps (SAC, TQC, CrossQ);
    None where rollouts are counted in episodes (``train_freq: [n, episode]``), whose length varies."""
    left = params.n_timesteps - start
    if left <= 0:
        return start
    if params.algo == "ppo":
        per_env = params.algo_kwargs.get("n_steps", 2048)
    else:
        frequency = params.algo_kwargs.get("train_freq", 1)
        count, unit = (frequency, "step") if isinstance(frequency, int) else tuple(frequency)
        if unit != "step":
            return None
        per_env = count
    chunk = params.n_envs * per_env
    return start + -(-left // chunk) * chunk


def _best_copy(steps: int) -> str:
    """The folder in ``checkpoints/`` keeping the best model evaluated at ``steps``."""
    return f"best_policy_{steps}_steps"


def _best_steps(evaluations: list[dict[str, Any]]) -> int | None:
    """The step of the last evaluation marked best (its model is the best on disk), None if none is."""
    return max((row["timesteps"] for row in evaluations if row.get("best")), default=None)


def _saved_steps(policy: Path) -> int | None:
    """The step of the model in the policy folder ``policy`` by its card; None if it has none."""
    try:
        return json.loads((policy / CARD_FILE).read_text(encoding="utf-8")).get("timesteps")
    except (OSError, ValueError, AttributeError):
        return None


def _keep_best_copy(checkpoints: Path, steps: int | None) -> None:
    """Remove every best model kept in ``checkpoints`` (and any swap's leftovers) but the one of ``steps``."""
    for path in checkpoints.glob("*best_policy_*"):
        if steps is None or path.name != _best_copy(steps):
            shutil.rmtree(path, ignore_errors=True)


def _next_multiple(steps: int, every: int) -> int:
    return (steps // every + 1) * every


class NormalizedPolicy:
    """A stable-baselines3 model reading raw observations through its VecNormalize statistics."""

    def __init__(self, model, normalization) -> None:
        self.model, self.normalization = model, normalization

    def predict(self, observation: np.ndarray, deterministic: bool = True):
        if self.normalization is not None:
            observation = self.normalization.normalize_obs(observation)
        return self.model.predict(observation, deterministic=deterministic)


def validation_settings(env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The training environment's settings without how the policy acts (the registry's
    ``ACTING_KEYS``: the speed action, every sensor shown, no residual; a deployed policy's
    controller composes the residual and hides what the policy is not shown itself) and with the
    validation schedules; no id's registered defaults (a residual action) come back."""
    from microg_env.scenarios import VALIDATION_SAMPLER

    kwargs = {k: v for k, v in env_kwargs.items() if k not in ACTING_KEYS}
    return kwargs | {"scenario_sampler": VALIDATION_SAMPLER}


def validation_runs(env_kwargs: dict[str, Any], controller, episodes: int) -> tuple[list, float]:
    """The metrics and failure rate of ``controller`` on the first ``episodes`` validation
    episodes (seeds from :data:`VALIDATION_SEED`) of the task of ``env_kwargs``, in one batch."""
    from microg_env.rollout.batch import evaluate_batch

    seeds = range(VALIDATION_SEED, VALIDATION_SEED + episodes)
    return evaluate_batch(validation_settings(env_kwargs), controller, seeds)


def _show(value: float | None, spec: str) -> str:
    return "n/a" if value is None or not math.isfinite(value) else format(value, spec)


def _json_number(value):
    """JSON has no infinity or NaN: they are written as null."""
    return value if not isinstance(value, float) or math.isfinite(value) else None


def _read_json(path: Path, default):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return default
