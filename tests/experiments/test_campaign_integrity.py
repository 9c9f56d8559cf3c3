"""Campaigns and study pages that would print a wrong number with nothing said (#44): a run's
identity (a policy by its contents), a parameter named twice, the sensitivity page's rows matched by
run, and the faults a campaign is refused for at load instead of after its runs."""

from __future__ import annotations

import itertools
import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from microg_env.controllers.registry import BEHAVIOUR_FILES, shipped_policy_folder
from microg_env.experiments.campaign import Campaign
from microg_env.experiments.comparison import compare
from microg_env.experiments.distributed import check_folder
from microg_env.experiments.store import result_row
from microg_env.experiments.studies import STUDIES, write_study
from microg_env.experiments.studies.groups import page_header
from microg_env.rollout.runner import RunResult
from microg_env.rollout.spec import RunSpec
from microg_env.validate import shown

REPO = Path(__file__).resolve().parents[2]
SHORT = {"scenario": "condition-2", "duration_s": 0.3}
GAIN, FRICTION = "servo.speed_loop_gain_hz", "qzs.guide_friction_n"


# -- a policy is its contents ----------------------------------------------------------------------


def _policy(folder: Path, shipped: str) -> Path:
    """``folder`` holding the files that make the shipped policy ``shipped`` act (replacing any there)."""
    folder.mkdir(exist_ok=True)
    for name in BEHAVIOUR_FILES:
        shutil.copyfile(shipped_policy_folder(shipped) / name, folder / name)
    return folder


def test_a_policy_folder_given_new_contents_is_a_new_run_and_its_old_spec_is_refused(tmp_path, monkeypatch):
    """A campaign re-run after polA was replaced found its runs "already stored" (the hash read the
    path) and kept the old policy's numbers."""
    monkeypatch.chdir(tmp_path)
    _policy(tmp_path / "polA", "residual-sac-setpoint")
    before = RunSpec(controller="polA", **SHORT)
    written = json.loads(json.dumps(before.as_dict()))
    assert RunSpec.from_dict(written) == before
    _policy(tmp_path / "polA", "gains-ppo")
    after = RunSpec(controller="polA", **SHORT)
    assert after.hash != before.hash
    assert after.hash == RunSpec(controller="gains-ppo", **SHORT).hash
    with pytest.raises(ValueError, match=r"controller_digest .*'polA'.*\(its files changed"):
        RunSpec.from_dict(written)  # a stored spec is not re-run on other contents


def test_a_policy_whose_files_change_after_its_run_was_specified_is_not_run_as_it(tmp_path, monkeypatch):
    """A campaign whose policy folder was replaced while it ran stored a run of the new policy under
    the old one's identity (the digest was read when the spec was made, the network when it ran),
    and reused that row for ever."""
    from microg_env.rollout.runner import run, run_all

    monkeypatch.chdir(tmp_path)
    _policy(tmp_path / "polA", "residual-sac-setpoint")
    spec = RunSpec(controller="polA", **SHORT)
    _policy(tmp_path / "polA", "gains-ppo")  # retrained into the same folder meanwhile
    changed = "policy folder 'polA' changed since the run was specified"
    with pytest.raises(ValueError, match=changed):
        run(spec)
    (result,) = run_all([spec])  # a campaign's batches
    assert not result.ok
    assert changed in result.error


def test_every_spelling_of_one_policy_is_one_controller(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _policy(tmp_path / "polA", "residual-sac-setpoint")
    spellings = ["polA", "./polA", str(tmp_path / "polA"), "residual-sac-setpoint"]
    assert len({RunSpec(controller=name, **SHORT).hash for name in spellings}) == 1
    with pytest.raises(ValueError, match=r"are the same run"):
        Campaign.from_dict({"name": "t", "base": SHORT, "sweep": {"controller": ["polA", "./polA"]}})
    with pytest.raises(ValueError, match=r"controller './polA' is given twice \(as 'polA' too\)"):
        compare(["polA", "./polA"], scenarios=["condition-2"], seeds=1, duration_s=0.1)


@pytest.mark.slow
def test_every_committed_study_row_keeps_its_spec_hash():
    """A classical controller's hash is what it was (no digest in its spec); a shipped policy's row
    carries the digest its hash is of."""
    for table in sorted((REPO / "docs" / "studies").glob("*/results.parquet")):
        rows = pq.read_table(table, columns=["spec_hash", "spec"]).to_pylist()
        for row in rows:
            spec = RunSpec.from_dict(json.loads(row["spec"]))
            assert spec.hash == row["spec_hash"], (table.parent.name, row["spec"])
            assert ("controller_digest" in row["spec"]) == (spec.controller_digest is not None)


# -- a parameter is named once -------------------------------------------------------------------

#: Parameters by kind: (their spellings, how base fixes one and that spelling, two values, a distribution).
PARAMETERS = {
    "rig parameter": (
        ("pad.stiffness_n_per_m", "overrides.pad.stiffness_n_per_m"),
        ({"overrides": {"pad.stiffness_n_per_m": 6000.0}}, "overrides.pad.stiffness_n_per_m"),
        [5000.0, 6000.0],
        {"uniform": [5000.0, 7000.0]},
    ),
    "PID gain": (
        ("gains.ki_per_s2",),
        ({"gains": {"ki_per_s2": 5000.0}}, "gains.ki_per_s2"),
        [4000.0, 5000.0],
        {"uniform": [4000.0, 6000.0]},
    ),
    "imperfection": (
        ("imperfections.friction",),
        ({"imperfections": {"friction": False}}, "imperfections.friction"),
        [True, False],
        {"choice": [True, False]},
    ),
    "run spec field": (
        ("control_period_us",),
        ({"control_period_us": 500.0}, "control_period_us"),
        [500.0, 1000.0],
        {"choice": [500.0, 1000.0]},
    ),
}
PLACES = ("base", "sweep", "joined sweep", "samples.draw")


def _put(data: dict, kind: str, place: str, spelling: str) -> str:
    """Name the ``kind`` parameter in ``data`` at ``place`` as ``spelling``; the spelling a message shows."""
    _, (base, base_spelling), values, distribution = PARAMETERS[kind]
    if place == "base":
        for key, value in base.items():
            data["base"][key] = value | data["base"].get(key, {}) if isinstance(value, dict) else value
        return base_spelling
    if place == "sweep":
        data["sweep"][spelling] = values
    elif place == "joined sweep":
        data["sweep"][f"{spelling}, sensors.ruler_noise_m"] = [[value, 2e-9] for value in values]
    else:
        data.setdefault("samples", {"count": 1, "draw": {}})["draw"][spelling] = distribution
    return spelling


def _twice() -> list:
    """Every parameter named twice: each pair of places (a place twice where it can hold two
    spellings; a joined sweep key twice: both in one entry), each pair of its spellings."""
    cases = []
    for kind, (spellings, *_) in PARAMETERS.items():
        for first, second in itertools.combinations_with_replacement(PLACES, 2):
            for a, b in itertools.product(spellings, repeat=2):
                if first == second and (first == "base" or (a >= b and first != "joined sweep")):
                    continue  # base has one way to name it; a mapping holds a key once
                cases.append(pytest.param(kind, (first, a), (second, b), id=f"{kind}:{first}:{a}+{second}:{b}"))
    return cases


@pytest.mark.parametrize(("kind", "first", "second"), _twice())
def test_a_parameter_named_twice_is_refused_naming_both_spellings(kind, first, second):
    """``pad.stiffness_n_per_m`` swept and ``overrides.pad.stiffness_n_per_m`` drawn ran one key's
    values while the table recorded the other's; a sweep beside a draw of one key, a key in base
    and varied, and one key twice in a joined sweep key were each accepted."""
    data = {"name": "t", "base": dict(SHORT), "sweep": {}}
    if first[0] == second[0] == "joined sweep":
        values = PARAMETERS[kind][2]
        data["sweep"][f"{first[1]}, {second[1]}"] = [list(values)]
        shown_as = [first[1], second[1]]
    else:
        shown_as = [_put(data, kind, *first), _put(data, kind, *second)]
    with pytest.raises(ValueError, match="name it once") as refused:
        Campaign.from_dict(data)
    message = str(refused.value)
    assert "\n" not in message
    for spelling in shown_as:
        assert shown(spelling) in message


@pytest.mark.parametrize("kind", PARAMETERS)
@pytest.mark.parametrize("place", PLACES)
def test_a_parameter_named_once_anywhere_is_taken(kind, place):
    """The check refuses only a second name: each kind, named once in each place, loads."""
    data = {"name": "t", "base": dict(SHORT), "sweep": {}}
    _put(data, kind, place, PARAMETERS[kind][0][-1])
    assert Campaign.from_dict(data).runs()


# -- the sensitivity page ------------------------------------------------------------------------

MORRIS = {
    "name": "m",
    "base": SHORT,
    "sweep": {"controller": ["pid", "feedforward"]},
    "samples": {
        "method": "morris",
        "trajectories": 3,
        "levels": 4,
        "seed": 1,
        "draw": {GAIN: {"uniform": [50.0, 200.0]}, FRICTION: {"uniform": [0.05, 0.2]}},
    },
    "seeds": [1000, 1001],
    "report": "sensitivity",
}
#: The stand-in x at the collision (m): each controller's own size, moved by the speed loop and the seed.
SIZE_M, SEED_SHIFT_M = {"pid": 8e-6, "feedforward": 0.2e-6}, {"pid": 1e-6, "feedforward": 0.05e-6}


def _collision_x(controller: str, point: dict, seed: int) -> float:
    return SIZE_M[controller] * (1.0 + point[GAIN] / 100.0) + SEED_SHIFT_M[controller] * (seed - 1000)


def _sensitivity_table(campaign: Campaign) -> pa.Table:
    """A results table of ``campaign`` whose only headline is :func:`_collision_x`."""
    rows = []
    for run in campaign.runs():
        x = _collision_x(run.spec.controller, run.columns, run.spec.seed)
        rows.append(
            {
                "spec_hash": run.spec.hash,
                "status": "ok",
                "scenario": run.spec.scenario,
                "controller": run.spec.controller,
                "seed": run.spec.seed,
                "termination_reason": None,
                "compensation_error_pct": None,
                "x_change_after_touchdown_m": None,
                "max_deformation_m": 1.0,
                "reference_max_deformation_m": 1.0,
                "flexible_unit_excursion_collision_m": x,
                **run.columns,
            }
        )
    return pa.Table.from_pylist(rows)


@pytest.mark.slow
def test_the_sensitivity_page_analyses_each_controller_on_its_own_over_the_mean_of_its_seeds(tmp_path):
    """The page keyed rows by (scenario, drawn values): a two-controller campaign's page showed the
    feed-forward's numbers alone and a two-seed page the last seed's, saying "one seed"."""
    campaign = Campaign.from_dict(MORRIS)
    page = write_study(campaign, _sensitivity_table(campaign), tmp_path).read_text()
    assert "2 seeds (1000, 1001), each point's quantity the mean over them" in page
    assert "one seed" not in page
    sections = page.split("\n## `controller` = ")[1:]
    assert [section.split("\n")[0] for section in sections] == ["pid", "feedforward"]
    points = campaign.sample_points()
    for controller, section in zip(["pid", "feedforward"], sections, strict=True):
        per_point = np.mean(
            [[_collision_x(controller, p, seed) * 1e6 for p in points] for seed in (1000, 1001)], axis=0
        )
        low, high = np.percentile(per_point, [5, 95])
        spread = f"{np.median(per_point):.3g} | {low:.3g} to {high:.3g} | 3 of 3"
        assert f"| x at the collision (max over contact) (µm) | condition-2 | {spread} |" in section
        assert "0 of 12 runs ended at a stroke limit" in section  # 24 runs: the design repeats points


def test_the_sensitivity_page_refuses_a_table_without_a_run_of_its_design(tmp_path):
    campaign = Campaign.from_dict(MORRIS)
    table = _sensitivity_table(campaign)
    with pytest.raises(ValueError, match=r"has no row of 1 of the design's \d+ runs .*not this campaign's table"):
        write_study(campaign, table.slice(1), tmp_path)


@pytest.mark.parametrize(
    ("samples", "named"),
    [
        (None, "reads a Morris design (samples: {method: morris, ...}), got no samples"),
        ({"count": 3, "draw": {FRICTION: {"uniform": [0.1, 0.2]}}}, "got random samples"),
        (
            {"method": "morris", "trajectories": 2, "draw": {"gains.ki_per_s2": {"uniform": [4000.0, 6000.0]}}},
            "moves rig parameters only (its page gives each one's assumed value); 'gains.ki_per_s2' is not one",
        ),
    ],
)
def test_a_sensitivity_report_the_page_cannot_read_is_refused_at_load(samples, named):
    """Each crashed the page after every run had run."""
    data = {"name": "t", "base": SHORT, "report": "sensitivity"} | ({"samples": samples} if samples else {})
    with pytest.raises(ValueError, match=re.escape(named)):
        Campaign.from_dict(data)


# -- study pages -----------------------------------------------------------------------------------

#: A campaign each study page takes (its swept columns), short runs.
REPORTED = {
    "period-bandwidth": {"sweep": {GAIN: [100.0, 150.0]}},
    "fifty-gram-floor": {
        "sweep": {
            FRICTION: [0.1],
            "sensors.ruler_resolution_m": [5e-9],
            "sensors.accelerometer_bias_m_s2": [0.0],
            "sensors.ruler_zero_offset_m": [0.0],
        }
    },
    "landing-monte-carlo": {"sweep": {"controller": ["pid", "feedforward"]}},
    "sensitivity": {"samples": MORRIS["samples"]},
    "controller-sensitivity": {"samples": MORRIS["samples"], "sweep": {"controller": ["pid", "feedforward"]}},
    "transmission": {"sweep": {"screw.transmission_stiffness_n_per_m": [1e8, float("inf")]}},
}


@pytest.mark.parametrize("study", sorted(STUDIES))
def test_a_study_page_says_so_when_no_run_completed(study, tmp_path):
    """The period-bandwidth and transmission pages crashed on a table of failed runs."""
    assert sorted(REPORTED) == sorted(STUDIES)
    campaign = Campaign.from_dict({"name": "t", "base": SHORT, "report": study} | REPORTED[study])
    rows = [result_row(RunResult(run.spec, None, "RuntimeError: boom"), run.columns) for run in campaign.runs()]
    page = write_study(campaign, pa.Table.from_pylist(rows), tmp_path).read_text()
    assert "No run completed, so this page has no numbers." in page
    assert f"- {len(rows)} of {len(rows)} runs: RuntimeError: boom" in page


def test_a_study_page_names_the_campaign_file_that_ran(tmp_path):
    """Every page said it came from studies/<name>.yml, whatever file ran."""
    path = tmp_path / "mine" / "trial.yml"
    path.parent.mkdir()
    path.write_text("name: landing\nbase: {scenario: condition-2, duration_s: 0.3}\nreport: landing-monte-carlo\n")
    table = pa.table({"status": ["ok"]})
    header = "\n".join(page_header(Campaign.load(path), table, tmp_path / "out"))
    assert f"`microg campaign {path.as_posix()} --out {(tmp_path / 'out').as_posix()}`" in header
    built = "\n".join(page_header(Campaign.from_dict({"name": "landing", "base": SHORT}), table, tmp_path))
    assert "campaign `landing` (built in Python, not read from a file)" in built
    assert "studies/" not in header + built


# -- refused at load, not stored as failures -------------------------------------------------------


def test_a_uniform_range_wider_than_a_float_is_refused_at_load():
    """high - low overflowed: an OverflowError, not a message."""
    draw = {FRICTION: {"uniform": [-1e308, 1e308]}}
    with pytest.raises(ValueError, match=r"samples\.draw\.qzs\.guide_friction_n\.uniform: .* wider than a float"):
        Campaign.from_dict({"name": "t", "base": SHORT, "samples": {"count": 2, "draw": draw}})


def test_a_gain_the_pid_refuses_is_refused_at_load():
    """A negative Ki was stored as a failed run and the campaign exited 0."""
    with pytest.raises(ValueError, match=r"RunSpec\.gains: PIDGains\.ki_per_s2 must be a finite number >= 0, got -5"):
        Campaign.from_dict({"name": "t", "base": SHORT, "sweep": {"gains.ki_per_s2": [-5]}})
    with pytest.raises(ValueError, match=r"PIDGains\.kd must be"):
        RunSpec(controller="pid-dom", gains={"kd": -1.0})


@pytest.mark.parametrize("record", ["{not json", "[1, 2]", '{"nom": "t"}', "\udcff"])
def test_a_damaged_campaign_record_is_named_with_its_fault(tmp_path, record):
    """A damaged campaign.json was reported as the results of "campaign None"."""
    path = tmp_path / "campaign.json"
    path.write_bytes(record.encode("utf-8", "surrogateescape"))
    with pytest.raises(ValueError, match=re.escape(f"its campaign record {str(path)!r} cannot be read (")) as refused:
        check_folder(Campaign.from_dict({"name": "t", "base": SHORT}), tmp_path)
    assert "None" not in str(refused.value)
    assert "\n" not in str(refused.value)


@pytest.mark.slow
def test_the_campaign_command_exits_2_on_a_damaged_campaign_record(tmp_path):
    path, out = tmp_path / "c.yml", tmp_path / "out"
    path.write_text("name: mine\nbase: {scenario: condition-2, duration_s: 0.1}\n")
    out.mkdir()
    (out / "campaign.json").write_text("{half written")
    done = subprocess.run(
        [sys.executable, "-m", "microg_env.cli", "campaign", str(path), "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert done.stderr.count("\n") == 1
    assert f"{str(out / 'campaign.json')!r} cannot be read (Expecting property name" in done.stderr
    assert (out / "campaign.json").read_text() == "{half written"
    assert sorted(p.name for p in out.iterdir()) == ["campaign.json"]


# -- a design is the same on every CPU -------------------------------------------------------------


@pytest.mark.parametrize("method", ["morris", "random"])
def test_log_uniform_draws_do_not_move_with_the_last_bit_of_exp(method, monkeypatch):
    """The committed sensitivity study's log-uniform values were drawn by NumPy's AVX-512 exp; on a
    CPU without AVX-512 66 of its 270 runs hashed differently (the last bit of 0.00043088693800637646).
    An exp one unit in the last place off must give the same design."""
    draw = {"servo.torque_filter_s": {"loguniform": [2.0e-4, 2.0e-3]}, GAIN: {"uniform": [50, 200]}}
    samples = {"method": "morris", "trajectories": 4, "seed": 0} if method == "morris" else {"count": 30}
    data = {"name": "log-draws", "base": SHORT, "samples": {**samples, "draw": draw}}
    exact = [run.spec.hash for run in Campaign.from_dict(data).runs()]
    exp, np_exp = math.exp, np.exp
    monkeypatch.setattr(math, "exp", lambda x: float(np.nextafter(exp(x), np.inf)))
    monkeypatch.setattr(np, "exp", lambda x, *a, **k: np.nextafter(np_exp(x, *a, **k), np.inf))
    assert [run.spec.hash for run in Campaign.from_dict(data).runs()] == exact


def test_a_stored_error_carries_no_terminal_codes():
    """A Ray worker's error came with its colour codes into the table (``\\x1b[36mray::_run_task()``)."""
    spec = RunSpec(**SHORT)
    row = result_row(RunResult(spec, None, "RayTaskError(ValueError): \x1b[36mray::_run_task()\x1b[39m (pid=1)"), {})
    assert row["error"] == "RayTaskError(ValueError): ray::_run_task() (pid=1)"
