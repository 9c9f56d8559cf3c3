"""A campaign file: a base :class:`~microg_env.rollout.spec.RunSpec`, a full grid (``sweep:``),
Monte Carlo draws (``samples:``) and seeds, expanded to the campaign's runs.

.. code-block:: yaml

    name: period-bandwidth          # required
    description: free text
    rig: my-rig.toml                # a rig file, relative to this file (default: the paper's rig)
    base:                           # RunSpec fields (defaults: the RunSpec's)
      scenario: condition-1
      duration_s: 7
    sweep:                          # every combination of these lists
      control_period_us: [1000, 500, 200, 100]
      servo.speed_loop_gain_hz: [50, 100, 200]
      controller: [pid-retuned, feedforward]
      qzs.guide_friction_n, qzs.guide_static_friction_n: [[0.1, 0.125], [0.2, 0.25]]  # together
    samples:                        # count draws, each a point; from its own generator seed
      count: 20
      seed: 0
      draw:
        qzs.guide_friction_n: {uniform: [0.1, 0.5]}
        pad.stiffness_n_per_m: {loguniform: [4666, 9387]}
    # or a Morris design for a global sensitivity analysis (SALib): trajectories x (keys + 1)
    # points, each moving one key at a time on a grid of levels over its range
    #   samples: {method: morris, trajectories: 8, levels: 4, seed: 0,
    #             draw: {servo.speed_loop_gain_hz: {uniform: [40, 200]}, ...}}
    seeds: {first: 1000, count: 3}  # or a list
    report: period-bandwidth        # a study page to write (microg_env.experiments.studies)

A key names a RunSpec field (``controller``, ``control_period_us``, ...), a PID gain
(``gains.ki_per_s2``), an imperfection (``imperfections.friction``), a rig parameter by dotted
path (``qzs.guide_friction_n``) or one of the plant alone, which the controllers do not know
(``plant_overrides.servo.speed_loop_gain_hz``). Keys joined by commas vary together: each value is a list of
one value per key. A parameter is named once in the file (``pad.stiffness_n_per_m`` and
``overrides.pad.stiffness_n_per_m`` are one: fixed in ``base``, swept or drawn, not two of these);
the rig file's parameters hold where the file names none of them.
Runs = grid points x samples x seeds. A Morris design takes only uniform and
loguniform ranges (a loguniform key is gridded in its logarithm) and is drawn by
:func:`morris_design`, whose unit coordinates the sensitivity page reads back
(:meth:`Campaign.morris_design`).
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from microg_env import validate
from microg_env.files import read_yaml
from microg_env.rollout.spec import NESTED_FIELDS, RunSpec, spec_entry
from microg_env.validate import shown

#: The distributions ``samples:`` draws from, with their arguments.
DISTRIBUTIONS = {
    "uniform": "[low, high]",
    "loguniform": "[low, high], both > 0",
    "normal": "[mean, standard deviation]",
    "choice": "[a list of values]",
}
#: What a campaign's name may be (it names its default folder).
NAME_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}")
#: Most runs one campaign may hold.
MAX_RUNS = 1_000_000
_TOP_KEYS = ("name", "description", "rig", "base", "sweep", "samples", "seeds", "report", "batch_size")
#: Specs one Ray task runs as rigs of one batch at most (a task lost to Ctrl-C loses this many).
DEFAULT_BATCH_SIZE = 16


@dataclass(frozen=True)
class Run:
    """One run of a campaign: its spec and the values of the campaign's columns (swept, sampled)."""

    spec: RunSpec
    columns: dict[str, Any]


@dataclass(frozen=True)
class Campaign:
    """A parsed campaign file (module docstring)."""

    name: str
    description: str
    base: dict[str, Any]
    sweep: dict[str, list]
    samples: dict[str, Any] | None
    seeds: tuple[int, ...]
    report: str | None
    batch_size: int
    #: The file it was read from, as given (None: built from a mapping).
    source: str | None = field(default=None, compare=False)

    @classmethod
    def load(cls, path: str | Path) -> Campaign:
        """The campaign of a YAML file; a bad file raises ValueError naming the file and the fault."""
        path = Path(path)
        data = read_yaml(path, "campaign file")
        try:
            return cls.from_dict(data, str(path))
        except ValueError as error:
            raise ValueError(f"campaign file {shown(str(path))}: {error}") from None

    @classmethod
    def from_dict(cls, data: object, source: str | None = None) -> Campaign:
        if not isinstance(data, Mapping):
            raise ValueError(f"must be a mapping with keys {', '.join(_TOP_KEYS)}, got {shown(data)}")
        unknown = sorted(set(data) - set(_TOP_KEYS))
        if unknown:
            raise ValueError(f"unknown key {shown(unknown[0])}; known: {', '.join(_TOP_KEYS)}")
        name = data.get("name")
        if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
            raise ValueError(f"name must be letters, digits, '.', '_' or '-' (a folder name), got {shown(name)}")
        base = {} if data.get("base") is None else data["base"]
        validate.instance("base", base, Mapping)
        _check_keys("base", base)
        if "seed" in base:
            raise ValueError("base: give seeds in seeds:, not seed")
        for key in ("overrides", "gains", "imperfections"):
            if key in base and not isinstance(base[key], Mapping):
                raise ValueError(f"base: {key} must be a mapping, got {shown(base[key])}")
        sweep = {} if data.get("sweep") is None else data["sweep"]
        validate.instance("sweep", sweep, Mapping)
        _check_keys("sweep", sweep)
        for key, values in sweep.items():
            if "seed" in _keys(key):
                raise ValueError("sweep: give seeds in seeds:, not seed")
            if not isinstance(values, list) or not values:
                raise ValueError(f"sweep: {key} must be a non-empty list, got {shown(values)}")
            keys = _keys(key)
            if len(keys) > 1 and not all(isinstance(v, list) and len(v) == len(keys) for v in values):
                raise ValueError(
                    f"sweep: each value of {shown(key)} must be a list of {len(keys)} values, got {shown(values)}"
                )
        samples = data.get("samples")
        if samples is not None:
            _check_samples(samples)
        _check_named_once(base, sweep, samples["draw"] if samples is not None else {})
        report = data.get("report")
        batch_size = validate.integer("batch_size", data.get("batch_size", DEFAULT_BATCH_SIZE), 1, 256)
        base = dict(base)
        if data.get("rig") is not None:  # the rig's parameters, under base's and the sweep's
            base["overrides"] = _rig_overrides(data["rig"], source) | dict(base.get("overrides", {}))
        campaign = cls(
            name.strip(),
            str(data.get("description") or ""),
            base,
            {str(k): list(v) for k, v in sweep.items()},
            samples,
            _seeds(data.get("seeds", [0])),
            report,
            batch_size,
            source,
        )
        if report is not None:
            from microg_env.experiments.studies import STUDIES

            validate.choice("report", report, tuple(STUDIES))
            missing = [c for c in STUDIES[report].COLUMNS if c not in campaign.columns]
            if missing:
                raise ValueError(f"report {shown(report)} needs {', '.join(missing)} swept or sampled")
            check = getattr(STUDIES[report], "check", None)
            if check is not None:
                check(campaign)
        campaign.runs()  # every run's spec is checked now, before anything starts
        return campaign

    @property
    def columns(self) -> tuple[str, ...]:
        """The keys the campaign varies (swept, then sampled), each a column of its results."""
        drawn = tuple(self.samples["draw"]) if self.samples else ()
        return tuple(k for key in self.sweep for k in _keys(key)) + drawn

    @property
    def _morris(self) -> bool:
        return bool(self.samples) and self.samples.get("method", "random") == "morris"

    def morris_design(self) -> np.ndarray:
        """The unit-cube points of this campaign's Morris design (``samples: {method: morris}``)."""
        return morris_design(self.samples)

    def sample_points(self) -> list[dict[str, Any]]:
        """The sampled points in order, each a mapping of key to value (a Morris design's rows,
        repeats included, where :meth:`runs` runs a repeated point once)."""
        return _draws(self.samples)

    def _grid_points(self) -> list[dict[str, Any]]:
        """The sweep's points in order, each a mapping of swept key to value (joined keys apart)."""
        points = []
        for values in itertools.product(*self.sweep.values()):
            point = {}
            for key, value in zip(self.sweep, values, strict=True):
                keys = _keys(key)
                point |= dict(zip(keys, value, strict=True)) if len(keys) > 1 else {key: value}
            points.append(point)
        return points

    def _specs(self) -> Iterator[tuple[int, dict[str, Any], int, RunSpec]]:
        """(grid point's index, the columns' values, seed, spec) of every grid point x sample x seed,
        in that nesting order, a point a Morris design repeats each time."""
        draws = sample_count(self.samples) if self.samples else 1
        total = math.prod(len(v) for v in self.sweep.values()) * draws * len(self.seeds)
        if total > MAX_RUNS:
            raise ValueError(f"{total} runs, more than {MAX_RUNS}")
        draws = _draws(self.samples) if self.samples else [{}]
        for where, point in enumerate(self._grid_points()):
            for draw in draws:
                values = point | draw
                fields_ = _spec_fields(self.base, values)
                for seed in self.seeds:
                    yield where, values, seed, RunSpec.from_dict(fields_ | {"seed": seed})

    def runs(self) -> list[Run]:
        """Every run: grid points x samples x seeds, in that nesting order (a point a Morris design
        repeats, once)."""
        out, seen = [], {}
        for where, values, seed, spec in self._specs():
            if spec.hash in seen:
                if self._morris and seen[spec.hash][0] == (where, seed):  # trajectories share a point: once
                    continue
                raise ValueError(f"runs {seen[spec.hash][1]} and {values} are the same run (seed {seed})")
            seen[spec.hash] = ((where, seed), values)
            out.append(Run(spec, values))
        return out

    def sample_runs(self) -> list[tuple[dict[str, Any], int, list[RunSpec]]]:
        """For each grid point and seed: (the point, the seed, the spec of each of
        :meth:`sample_points` in order, a point a Morris design repeats each time), what a page
        matches its stored rows to by spec hash."""
        points, specs = self._grid_points(), {}
        for where, _, seed, spec in self._specs():
            specs.setdefault((where, seed), []).append(spec)
        return [(points[where], seed, of) for (where, seed), of in specs.items()]


def sample_count(samples: Mapping[str, Any]) -> int:
    """Points ``samples:`` draws: ``count``, or a Morris design's trajectories x (keys + 1)."""
    if samples.get("method", "random") == "morris":
        return samples["trajectories"] * (len(samples["draw"]) + 1)
    return samples["count"]


def _check_keys(where: str, mapping: Mapping) -> None:
    for key in mapping:
        if not isinstance(key, str):
            raise ValueError(f"{where}: keys must be names (strings), got {shown(key)}")


def _keys(key: str) -> list[str]:
    """The keys a sweep entry varies together (joined by commas)."""
    return [k.strip() for k in key.split(",")]


def _rig_overrides(rig: object, source: str | None) -> dict[str, Any]:
    """The parameters of the rig file ``rig`` (a path relative to the campaign file's folder)."""
    from microg_env.rigs import read_rig_option

    validate.instance("rig", rig, str)
    return read_rig_option(Path(rig) if source is None else Path(source).parent / rig, "rig").overrides


def _check_named_once(base: Mapping[str, Any], sweep: Mapping[str, Any], draw: Mapping[str, Any]) -> None:
    """ValueError naming both spellings if two keys of ``base``, ``sweep`` (joined keys each) and
    ``samples.draw`` land on one RunSpec entry (:func:`spec_entry`): the runs would take one key's
    value and the table record the other's."""
    named = [
        (f"{key}.{name}", "base", (key, name))
        for key, value in base.items()
        if key in NESTED_FIELDS and isinstance(value, Mapping)
        for name in value
    ]
    named += [(key, "base", (key,)) for key in base if key not in NESTED_FIELDS]
    named += [(key, "sweep", spec_entry(key)) for entry in sweep for key in _keys(entry)]
    named += [(key, "samples.draw", spec_entry(key)) for key in draw]
    seen: dict[tuple[str, ...], str] = {}
    for key, where, entry in named:
        spelled = f"{shown(key)} ({where})"
        if entry in seen:
            raise ValueError(f"{seen[entry]} and {spelled} set one parameter, {'.'.join(entry)}: name it once")
        seen[entry] = spelled


def _spec_fields(base: Mapping[str, Any], values: Mapping[str, Any]) -> dict[str, Any]:
    """RunSpec fields: ``base`` with each campaign key's value put where it belongs (:func:`spec_entry`)."""
    out = {key: (dict(value) if isinstance(value, Mapping) else value) for key, value in base.items()}
    for key in NESTED_FIELDS:
        out.setdefault(key, {})
    for key, value in values.items():
        entry = spec_entry(key)
        if len(entry) == 1:
            out[key] = value
        else:
            out[entry[0]][entry[1]] = value
    try:
        RunSpec.from_dict(out)
    except (ValueError, TypeError, AttributeError) as error:
        raise ValueError(f"at {dict(values)}: {error}") from None
    return out


def _seeds(value: object) -> tuple[int, ...]:
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - {"first", "count"})
        if unknown or "count" not in value:
            raise ValueError(f"seeds must be a list or {{first: N, count: M}}, got {shown(dict(value))}")
        first = validate.integer("seeds.first", value.get("first", 0), 0, 2**32 - 1)
        count = validate.integer("seeds.count", value["count"], 1, MAX_RUNS)
        return tuple(range(first, first + count))
    if not isinstance(value, list) or not value:
        raise ValueError(f"seeds must be a non-empty list or {{first: N, count: M}}, got {shown(value)}")
    seeds = tuple(validate.integer("seeds item", s, 0, 2**32 - 1) for s in value)
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds repeat a seed: {list(seeds)}")
    return seeds


#: The ways ``samples:`` draws its points: independent draws, or a Morris design.
SAMPLING_METHODS = ("random", "morris")


def _check_samples(samples: object) -> None:
    validate.instance("samples", samples, Mapping)
    method = samples.get("method", "random")
    validate.choice("samples.method", method, SAMPLING_METHODS)
    allowed = {"method", "seed", "draw"} | ({"count"} if method == "random" else {"trajectories", "levels"})
    unknown = sorted(set(samples) - allowed)
    if unknown:
        raise ValueError(f"samples: unknown key {shown(unknown[0])}; known for {method}: {', '.join(sorted(allowed))}")
    if method == "random":
        validate.integer("samples.count", samples.get("count"), 1, MAX_RUNS)
    else:
        validate.integer("samples.trajectories", samples.get("trajectories"), 2, MAX_RUNS)
        levels = validate.integer("samples.levels", samples.get("levels", 4), 2, 100)
        if levels % 2:
            raise ValueError(f"samples.levels must be even (Morris's one-step grid), got {levels}")
    validate.integer("samples.seed", samples.get("seed", 0), 0, 2**32 - 1)
    draw = samples.get("draw")
    if not isinstance(draw, Mapping) or not draw:
        raise ValueError(f"samples.draw must map keys to distributions, got {shown(draw)}")
    _check_keys("samples.draw", draw)
    for key, distribution in draw.items():
        if not isinstance(distribution, Mapping) or len(distribution) != 1:
            raise ValueError(
                f"samples.draw.{key} must be one of {{uniform|loguniform|normal|choice: [...]}}, "
                f"got {shown(distribution)}"
            )
        ((kind, args),) = distribution.items()
        if kind not in DISTRIBUTIONS:
            raise ValueError(
                f"samples.draw.{key}: unknown distribution {shown(kind)}; known: {', '.join(DISTRIBUTIONS)}"
            )
        if method == "morris" and kind not in ("uniform", "loguniform"):
            raise ValueError(f"samples.draw.{key}: a Morris design takes uniform or loguniform ranges, got {kind}")
        if kind == "choice":
            if not isinstance(args, list) or not args:
                raise ValueError(f"samples.draw.{key}.choice must be a non-empty list, got {shown(args)}")
            continue
        if not (isinstance(args, list) and len(args) == 2):
            raise ValueError(f"samples.draw.{key}.{kind} must be {DISTRIBUTIONS[kind]}, got {shown(args)}")
        a, b = (validate.finite(f"samples.draw.{key}.{kind}", v) for v in args)
        if kind == "uniform" and not math.isfinite(b - a):
            raise ValueError(f"samples.draw.{key}.uniform: {shown(args)} is wider than a float holds (high - low)")
        if (
            (kind in ("uniform", "loguniform") and not a < b)
            or (kind == "loguniform" and a <= 0)
            or (kind == "normal" and b <= 0)
        ):
            raise ValueError(f"samples.draw.{key}.{kind} must be {DISTRIBUTIONS[kind]} (low < high), got {shown(args)}")


def morris_design(samples: Mapping[str, Any]) -> np.ndarray:
    """A Morris design's points in the unit cube, (trajectories x (keys + 1), keys), keys in file
    order (SALib's sampler, seeded ``seed``)."""
    from SALib.sample import morris

    keys = list(samples["draw"])
    problem = {"num_vars": len(keys), "names": keys, "bounds": [[0.0, 1.0]] * len(keys)}
    return morris.sample(
        problem, samples["trajectories"], num_levels=samples.get("levels", 4), seed=samples.get("seed", 0)
    )


#: Significant digits a log-uniform value keeps (:func:`_exp`).
LOG_DRAW_DIGITS = 12


def _exp(logarithms: np.ndarray) -> np.ndarray:
    """Log-uniform values from their logarithms, kept to :data:`LOG_DRAW_DIGITS` significant digits:
    NumPy's vectorised ``exp`` differs in the last bit between CPUs (AVX-512 or not), and a drawn
    value enters a run's identity (its spec hash), so unrounded a design would differ by machine."""
    return np.array([float(f"{math.exp(v):.{LOG_DRAW_DIGITS}g}") for v in np.asarray(logarithms, dtype=float)])


def _from_unit(unit: np.ndarray, distribution: Mapping[str, list]) -> np.ndarray:
    ((kind, (low, high)),) = distribution.items()
    if kind == "loguniform":
        return _exp(math.log(low) + unit * (math.log(high) - math.log(low)))
    return low + unit * (high - low)


def _draws(samples: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The sampled points: ``count`` draws of every key from one generator seeded ``seed`` (keys
    drawn in file order), or a Morris design's points (:func:`morris_design`) in the keys' ranges."""
    if samples.get("method", "random") == "morris":
        unit = morris_design(samples)
        columns = {key: _from_unit(unit[:, j], d) for j, (key, d) in enumerate(samples["draw"].items())}
        return [{key: float(columns[key][i]) for key in columns} for i in range(unit.shape[0])]
    rng = np.random.default_rng(samples.get("seed", 0))
    count = samples["count"]
    columns = {}
    for key, distribution in samples["draw"].items():
        ((kind, args),) = distribution.items()
        if kind == "uniform":
            values = rng.uniform(args[0], args[1], count)
        elif kind == "loguniform":
            values = _exp(rng.uniform(math.log(args[0]), math.log(args[1]), count))
        elif kind == "normal":
            values = rng.normal(args[0], args[1], count)
        else:
            values = [args[i] for i in rng.integers(len(args), size=count)]
        columns[key] = [float(v) if isinstance(v, np.floating) else v for v in values]
    return [{key: columns[key][i] for key in columns} for i in range(count)]
