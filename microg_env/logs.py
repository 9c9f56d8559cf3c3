"""Rig logs: what a rig's real-time computer records each control period, in one schema for the
real rig and the model (``microg run --log`` writes it, ``microg replay`` and ``microg identify``
read it).

A log is a CSV file (or Parquet, with pyarrow) of one row per control period, uniform in time:

| column | unit | |
|---|---|---|
| ``time_s`` | s | from the test's start, one control period apart |
| ``command_m_s`` | m/s | the speed reference the controller sent the drive at that time, up positive |
| ``ruler_m`` | m | the grating ruler's reading of x (lander minus support, up positive) |
| ``encoder_m`` | m | the support's height above touchdown from the servo encoder |
| ``accelerometer_m_s2`` | m/s^2 | optional: the lander's accelerometer, g removed, up positive |
| ``pad_force_n`` | N | optional: the pad's force sensor |

Each row's readings are taken at its time and its command is computed from them. The test is
said in a TOML header, on the CSV's first lines after ``# `` (in Parquet, the file's metadata
under ``microg``): ``descent_height_m`` (the foot's start above the pad, m) and ``loads``, a
list of ``{ mass_kg = ..., height_m = ... }`` (``height_m`` left out: placed at the start). A
test starts balanced at rest, every imperfection of the rig on, as the paper's do (Section 4.1).
"""

from __future__ import annotations

import importlib.util
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from microg_env import validate
from microg_env.files import atomic_path, parse_toml
from microg_env.scenarios import LoadStep, Scenario

#: The columns every log has, then those it may have, in the order written.
REQUIRED_COLUMNS = ("time_s", "command_m_s", "ruler_m", "encoder_m")
OPTIONAL_COLUMNS = ("accelerometer_m_s2", "pad_force_n")
#: The first line of a CSV log, naming its schema's version.
CSV_MAGIC = "# microg rig log 1"
#: Suffixes of the formats read and written.
LOG_SUFFIXES = (".csv", ".parquet")
#: How far a row's time may stray from the uniform grid, in control periods (a real-time logger's
#: timestamp jitter; the replay takes the rows as uniform).
TIME_TOLERANCE = 0.1
#: What a Parquet log needs.
PARQUET_EXTRA = "Parquet logs need pyarrow: pip install 'microg-env[campaign]'"
#: Most rows a log may hold (a 30 s test at the fastest 100 us period is 300 000).
MAX_ROWS = 10_000_000
#: A replay window's default length, s (:func:`microg_env.rollout.replay.replay`): about the
#: e-folding time of the paper's lander, unstable on Eq. 17's negative residual stiffness.
DEFAULT_WINDOW_S = 0.1


@dataclass(frozen=True)
class RigLog:
    """A test's log: its ``columns`` (arrays of one length, at least :data:`REQUIRED_COLUMNS`),
    its start height and load schedule, and where it was read from."""

    columns: dict[str, np.ndarray]
    descent_height_m: float
    loads: tuple[LoadStep, ...]
    source: str = field(default="", compare=False)

    @property
    def control_period_s(self) -> float:
        time = self.columns["time_s"]
        return float((time[-1] - time[0]) / (len(time) - 1))

    @property
    def rows(self) -> int:
        return len(self.columns["time_s"])

    def scenario(self) -> Scenario:
        """The test as the model runs it: the log's schedule, as long as the log."""
        duration = self.rows * self.control_period_s
        return Scenario("log", self.loads, self.descent_height_m, duration_s=duration)

    def header(self) -> str:
        """The TOML header (without the ``# `` prefixes)."""
        loads = ", ".join(
            f"{{ mass_kg = {load.mass_kg!r} }}"
            if load.height_m is None
            else f"{{ mass_kg = {load.mass_kg!r}, height_m = {load.height_m!r} }}"
            for load in self.loads
        )
        return f"descent_height_m = {self.descent_height_m!r}\nloads = [{loads}]\n"


def check_log(log: RigLog, where: str) -> RigLog:
    """``log`` if it is a log of this schema; a ValueError starting with ``where`` otherwise."""
    missing = [name for name in REQUIRED_COLUMNS if name not in log.columns]
    if missing:
        raise ValueError(f"{where}: no column {missing[0]!r}; a log has {', '.join(REQUIRED_COLUMNS)}")
    unknown = sorted(set(log.columns) - set(REQUIRED_COLUMNS) - set(OPTIONAL_COLUMNS))
    if unknown:
        raise ValueError(
            f"{where}: unknown column {unknown[0]!r}; known: {', '.join(REQUIRED_COLUMNS + OPTIONAL_COLUMNS)}"
        )
    lengths = {len(values) for values in log.columns.values()}
    if len(lengths) != 1 or lengths.pop() < 2:
        raise ValueError(f"{where}: the columns must hold the same number of rows, at least 2")
    for name, values in log.columns.items():
        if not np.isfinite(values).all():
            row = int(np.flatnonzero(~np.isfinite(values))[0])
            raise ValueError(f"{where}: {name} is not a finite number in row {row + 1}")
    time, period = log.columns["time_s"], log.control_period_s
    grid = time[0] + period * np.arange(len(time))
    if not period > 0 or np.abs(time - grid).max() > TIME_TOLERANCE * period:
        row = int(np.argmax(np.abs(time - grid))) if period > 0 else 1
        raise ValueError(f"{where}: time_s must grow by one control period a row; row {row + 1} is at {time[row]!r} s")
    if log.rows > MAX_ROWS:
        raise ValueError(f"{where}: {log.rows} rows, more than {MAX_ROWS}")
    return log


def write_log(log: RigLog, path: str | Path) -> None:
    """Write ``log`` to ``path`` (``.csv``, or ``.parquet`` with pyarrow), atomically."""
    path = Path(path)
    names = [name for name in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS) if name in log.columns]
    if path.suffix == ".parquet":
        pa, pq = _pyarrow()
        table = pa.table({name: log.columns[name] for name in names})
        table = table.replace_schema_metadata({"microg": log.header()})
        with atomic_path(path) as temporary:
            pq.write_table(table, temporary)
        return
    text = io.StringIO()
    text.write(CSV_MAGIC + "\n")
    text.writelines(f"# {line}\n" for line in log.header().splitlines())
    np.savetxt(text, np.column_stack([log.columns[name] for name in names]), delimiter=",", fmt="%.17g",
               header=",".join(names), comments="")  # fmt: skip
    with atomic_path(path) as temporary:
        temporary.write_text(text.getvalue(), encoding="utf-8")


def read_log(path: str | Path) -> RigLog:
    """The log at ``path``; a one-line ValueError naming the file and the fault otherwise."""
    where = f"log {validate.shown(str(path))}"
    path = Path(path)
    if path.suffix not in LOG_SUFFIXES:
        raise ValueError(f"{where}: a log is a {' or '.join(LOG_SUFFIXES)} file")
    if not path.is_file():
        raise ValueError(f"{where} does not exist" if not path.exists() else f"{where} is not a regular file")
    try:
        header, columns = _read_parquet(path) if path.suffix == ".parquet" else _read_csv(path)
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise ValueError(f"{where} cannot be read: {validate.fault(error)}") from None
    try:
        meta = parse_toml(header)
    except ValueError as error:
        raise ValueError(f"{where}: its header is not TOML: {validate.fault(error)}") from None
    unknown = sorted(set(meta) - {"descent_height_m", "loads"})
    if unknown or "descent_height_m" not in meta or "loads" not in meta:
        raise ValueError(f"{where}: its header must give descent_height_m and loads, and nothing else")
    try:
        height = validate.positive("descent_height_m", meta["descent_height_m"], "m")
        validate.instance("loads", meta["loads"], list)
        loads = tuple(_load(entry) for entry in meta["loads"])
        Scenario("log", loads, height)  # the schedule's own checks
    except (TypeError, ValueError) as error:
        raise ValueError(f"{where}: {validate.fault(error)}") from None
    return check_log(RigLog(columns, height, loads, str(path)), where)


def _load(entry: object) -> LoadStep:
    if not isinstance(entry, dict) or set(entry) - {"mass_kg", "height_m"} or "mass_kg" not in entry:
        raise ValueError(f"each of loads must be {{ mass_kg = ..., height_m = ... }}, got {validate.shown(entry)}")
    return LoadStep(entry["mass_kg"], entry.get("height_m"))


def _read_csv(path: Path) -> tuple[str, dict[str, np.ndarray]]:
    text = path.read_text(encoding="utf-8")
    lines = text.splitlines()
    if not lines or lines[0].strip() != CSV_MAGIC:
        raise ValueError(f"its first line is not {CSV_MAGIC!r}")
    header = [line[2:] for line in lines[1:] if line.startswith("# ")]
    body = [line for line in lines[1:] if not line.startswith("#")]
    if not body:
        raise ValueError("it has no column names")
    names = [name.strip() for name in body[0].split(",")]
    if len(set(names)) < len(names):
        raise ValueError("a column is named twice")
    if len(body) < 3:
        raise ValueError("it has fewer than 2 rows")
    data = np.loadtxt(io.StringIO("\n".join(body[1:])), delimiter=",", ndmin=2, dtype=np.float64)
    if data.size and data.shape[1] != len(names):
        raise ValueError(f"{len(names)} column names for {data.shape[1]} columns")
    return "\n".join(header), {name: np.ascontiguousarray(data[:, i]) for i, name in enumerate(names)}


def _read_parquet(path: Path) -> tuple[str, dict[str, np.ndarray]]:
    _, pq = _pyarrow()
    table = pq.read_table(path)
    meta = (table.schema.metadata or {}).get(b"microg")
    if meta is None:
        raise ValueError("it has no microg header in its metadata")
    return meta.decode(), {name: table[name].to_numpy().astype(np.float64) for name in table.column_names}


def check_parquet_support(path: Path) -> None:
    """A ValueError naming what to install if ``path`` is a Parquet file and pyarrow is missing."""
    if Path(path).suffix == ".parquet" and importlib.util.find_spec("pyarrow") is None:
        raise ValueError(PARQUET_EXTRA)


def _pyarrow():
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise ValueError(PARQUET_EXTRA) from None
    return pa, pq
