"""Metrics of a run, computed from its :class:`~microg_env.trajectory.Trajectory` alone.

The quantities the paper and the field report (all SI, accelerations up positive):

* descent acceleration of each load stage, by a quadratic fit of the foot height over the stage's
  free fall (from ``SETTLE_S`` after the weight is placed to the next weight, the touchdown or the
  run's end), beside the ideal m g / (M + m); the compensation error a / a_ideal - 1 (Table 4)
  and the residual gravity error (a - a_ideal) / g; how much later than in the reference each
  weight placed in flight is placed (the paper's "lag of 3.9 s between the displacement and
  acceleration curves" of condition 3: a slow first stage reaches the second weight's height late);
* flexible-unit excursion max |x| in free fall (start to touchdown) and during the first contact;
  the paper's own quantity (Section 3.2: "the relative displacement change ... at the instant of
  collision and landing"), max |x(t) - x(touchdown)| over the first 5 and 10 ms of contact (the
  whole contact's max |x| is mostly the PID's integral lag, ~0.6 s after touchdown); the largest
  deviation of the support force from its balanced value; the servo's RMS torque (its
  continuous load, against the 48 N m rated);
* of the first contact: peak pad deformation, peak (collision) acceleration of the lander
  (Tables 3 and 6), contact time and restitution (Eqs. 7 and 9); the rebound height;
* fidelity against the ideal-microgravity reference (the same lander and pad in the uniform field
  m g / (M + m), no rig): its landing and the RMS foot-height error from the start to the apex of
  the reference's first rebound. (Not to the rebound's end: there both feet cross the pad's
  surface at full speed, so a 0.01 % difference in rebound speed moves the RMS by 2 %.)

A metric whose window the run did not complete (a free fall shorter than ``MIN_FIT_S`` after
settling, a contact without lift-off, a rebound without apex) is NaN, ``None`` in JSON, and
``RunMetrics.unavailable`` says why: never a number from the wrong window.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from microg_env.scenarios import SETTLE_S
from microg_env.trajectory import Trajectory

#: Shortest free fall (after settling) a descent acceleration is fitted over, s.
MIN_FIT_S = 1.0
#: Windows after the first touchdown over which the paper's "change at the instant of collision"
#: is read, s: ``RunMetrics.x_change_after_touchdown_m`` has one value per window. Not 1 ms: at the
#: default 1 ms control period that window holds one sample, and its value moves with where the
#: touchdown falls in the period (condition 3: 0.056 against 0.0002 um at a 4 times finer step).
INSTANT_WINDOWS_S = (5e-3, 10e-3)
#: The window ``microg compare`` reports: 5 ms.
COMPARED_WINDOW = INSTANT_WINDOWS_S.index(5e-3)


@dataclass(frozen=True)
class Contact:
    """One contact of the foot with the pad, with times interpolated between samples."""

    start: int  # first sample in contact
    end: int | None  # first sample after the pad's force has returned to zero; None: still on the pad
    touchdown_s: float
    liftoff_s: float  # NaN while on the pad
    impact_speed_m_s: float  # downward speed at touchdown
    exit_speed_m_s: float  # upward speed at lift-off; NaN while on the pad


def _interpolate(t0: float, t1: float, y0: float, y1: float, level: float = 0.0) -> float:
    """Time at which y, linear between (t0, y0) and (t1, y1), reaches ``level``."""
    return t0 if y1 == y0 else t0 + (level - y0) / (y1 - y0) * (t1 - t0)


def contacts(traj: Trajectory) -> list[Contact]:
    """Every contact: touchdown where the sole crosses the pad's surface, lift-off where the force
    ends; the last one has ``end`` None if the run ends with the foot on the pad."""
    height, force, t, v = traj.foot_height_m, traj.pad_force_n, traj.time_s, traj.lander_velocity_m_s
    found: list[Contact] = []
    i = 0
    while True:
        crossings = np.flatnonzero((height[i:-1] >= 0.0) & (height[i + 1 :] < 0.0))
        if crossings.size == 0:
            return found
        start = i + int(crossings[0]) + 1
        touchdown = _interpolate(t[start - 1], t[start], height[start - 1], height[start])
        impact = -float(np.interp(touchdown, t, v))
        pushing = np.flatnonzero(force[start:] > 0.0)
        released = np.flatnonzero(force[start + int(pushing[0]) :] <= 0.0) if pushing.size else np.array([])
        if released.size == 0:
            found.append(Contact(start, None, touchdown, math.nan, impact, math.nan))
            return found
        first_push = start + int(pushing[0])
        end = first_push + int(released[0])
        liftoff = t[end - 1]
        if end - 2 >= first_push and force[end - 2] > force[end - 1]:
            # The force falls to zero within the step before ``end``: extend its last slope.
            liftoff = min(_interpolate(t[end - 2], t[end - 1], force[end - 2], force[end - 1]), t[end])
        found.append(Contact(start, end, touchdown, liftoff, impact, float(np.interp(liftoff, t, v))))
        i = end


def stage_windows(traj: Trajectory, touchdown_index: int | None) -> list[tuple[int, int] | None]:
    """Sample ranges [i0, i1) of each load stage's free fall after settling (None: never placed)."""
    windows: list[tuple[int, int] | None] = []
    last = len(traj) if touchdown_index is None else touchdown_index
    for stage in range(len(traj.scenario.loads)):
        idx = np.flatnonzero(traj.stage == stage)
        if idx.size == 0:
            windows.append(None)
            continue
        i0 = int(np.searchsorted(traj.time_s, traj.time_s[idx[0]] + SETTLE_S))
        i1 = min(int(idx[-1]) + 1, last)
        windows.append((i0, max(i0, i1)))
    return windows


def descent_acceleration(traj: Trajectory, window: tuple[int, int]) -> float:
    """Second derivative of a least-squares parabola through the foot height over ``window``."""
    i0, i1 = window
    t = traj.time_s[i0:i1] - traj.time_s[i0]
    return float(2.0 * np.polyfit(t, traj.foot_height_m[i0:i1], 2)[0])


@dataclass(frozen=True)
class RunMetrics:
    """Everything ``microg run --json`` prints; NaN where ``unavailable`` gives the reason."""

    descent_accel_m_s2: list[float]
    ideal_descent_accel_m_s2: list[float]
    compensation_error_pct: list[float]
    residual_gravity_g: list[float]
    microgravity_level_g: list[float]
    #: The same descents as the lander's accelerometer reports them: its mean reading over each
    #: stage's fit window (bias and noise included; how an experiment without a position fit sees it).
    accelerometer_descent_accel_m_s2: list[float]
    #: Per weight placed in flight (``in_flight_weights``), its placement time minus the reference's, s.
    placement_delay_s: list[float]
    flexible_unit_excursion_free_fall_m: float
    flexible_unit_excursion_collision_m: float
    #: max |x(t) - x(touchdown)| over each of INSTANT_WINDOWS_S after the first touchdown.
    x_change_after_touchdown_m: list[float]
    support_force_variation_n: float
    servo_rms_torque_n_m: float
    max_deformation_m: float
    collision_accel_m_s2: float
    contact_time_s: float
    restitution: float
    impact_speed_m_s: float
    rebound_height_m: float
    reference_max_deformation_m: float
    reference_collision_accel_m_s2: float
    reference_contact_time_s: float
    reference_restitution: float
    reference_rms_height_error_m: float
    termination_reason: str | None
    unavailable: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict:
        """JSON-ready: NaN (a quantity the run did not reach) becomes None."""

        def clean(value):
            if isinstance(value, list):
                return [clean(v) for v in value]
            if isinstance(value, float) and not math.isfinite(value):
                return None
            return value

        return {key: clean(value) for key, value in asdict(self).items()}


@dataclass(frozen=True)
class LandingMetrics:
    """The first contact and its rebound; NaN where ``unavailable`` gives the reason."""

    max_deformation_m: float
    collision_accel_m_s2: float
    contact_time_s: float
    restitution: float
    impact_speed_m_s: float
    rebound_height_m: float
    rebound_apex_s: float  # time of the first rebound's apex
    unavailable: dict[str, str]


_CONTACT_METRICS = ("max_deformation_m", "collision_accel_m_s2", "contact_time_s", "restitution")
#: The per-stage metrics, all from the stage's descent fit.
_PER_STAGE = (
    "descent_accel_m_s2",
    "compensation_error_pct",
    "residual_gravity_g",
    "microgravity_level_g",
    "accelerometer_descent_accel_m_s2",
)


def landing(traj: Trajectory) -> LandingMetrics:
    """First-contact quantities of a run (NaN, with the reason, where the run did not reach them)."""
    found = contacts(traj)
    if not found:
        reason = "the run ended before the first touchdown"
        names = (*_CONTACT_METRICS, "impact_speed_m_s", "rebound_height_m")
        return LandingMetrics(*(math.nan,) * 7, unavailable=dict.fromkeys(names, reason))
    first = found[0]
    if first.end is None:
        reason = "the run ended before the first lift-off"
        unavailable = dict.fromkeys((*_CONTACT_METRICS, "rebound_height_m"), reason)
        return LandingMetrics(
            math.nan, math.nan, math.nan, math.nan, first.impact_speed_m_s, math.nan, math.nan, unavailable
        )
    unavailable = {}
    after = slice(first.end, found[1].start if len(found) > 1 else len(traj))
    rebound = traj.foot_height_m[after]
    velocity = traj.lander_velocity_m_s[after]
    if rebound.size and np.any(velocity <= 0.0):  # the apex was passed
        apex = int(np.argmax(rebound))
        rebound_height, rebound_apex = float(rebound[apex]), float(traj.time_s[after][apex])
    else:
        rebound_height = rebound_apex = math.nan
        unavailable["rebound_height_m"] = "the run ended before the rebound's apex"
    return LandingMetrics(
        max_deformation_m=float(-traj.foot_height_m[first.start : first.end].min()),
        collision_accel_m_s2=float(traj.lander_accel_m_s2[first.start : first.end].max()),
        contact_time_s=first.liftoff_s - first.touchdown_s,
        restitution=first.exit_speed_m_s / first.impact_speed_m_s,
        impact_speed_m_s=first.impact_speed_m_s,
        rebound_height_m=rebound_height,
        rebound_apex_s=rebound_apex,
        unavailable=unavailable,
    )


def compute_metrics(traj: Trajectory, reference: Trajectory) -> RunMetrics:
    """All metrics of ``traj``, with fidelity measured against the ideal-microgravity ``reference``."""
    g = traj.gravity_m_s2
    unavailable: dict[str, str] = {}
    found = contacts(traj)
    touchdown = found[0].start if found else None
    ideal = list(traj.scenario.ideal_descent_m_s2(traj.lander_mass_kg, g))
    measured, sensed = [], []
    windows = stage_windows(traj, touchdown)
    for i, window in enumerate(windows):
        reason = None
        if window is None:
            later = any(w is not None for w in windows[i + 1 :])
            reason = (
                f"load stage {i + 1}'s weight was placed together with the next, so it has no free fall of its own"
                if later
                else f"load stage {i + 1} was never reached"
            )
        else:
            i0, i1 = window
            span = traj.time_s[i1 - 1] - traj.time_s[i0] if i1 > i0 else 0.0
            if span < MIN_FIT_S:
                reason = (
                    f"load stage {i + 1}'s free fall lasted {max(span, 0.0):.2f} s after settling, "
                    f"under the {MIN_FIT_S:g} s a descent fit needs"
                )
        if reason is None:
            measured.append(descent_acceleration(traj, window))
            sensed.append(float(np.mean(traj.accelerometer_m_s2[window[0] : window[1]])))
            continue
        measured.append(math.nan)
        sensed.append(math.nan)
        for name in _PER_STAGE:
            unavailable[f"{name}[{i}]"] = reason
    delays = []
    for i, weight in enumerate(in_flight_weights(traj.scenario)):
        delay = placement_time(traj, weight) - placement_time(reference, weight)
        if not math.isfinite(delay):
            unavailable[f"placement_delay_s[{i}]"] = (
                f"the run or its reference ended before weight {weight + 1} was placed"
            )
        delays.append(delay)
    rig, ideal_landing = landing(traj), landing(reference)
    unavailable |= rig.unavailable
    unavailable |= {f"reference_{name}": reason for name, reason in ideal_landing.unavailable.items()}
    if touchdown is None:
        collision = math.nan
        unavailable["flexible_unit_excursion_collision_m"] = "the run ended before the first touchdown"
    elif found[0].end is None:
        collision = math.nan
        unavailable["flexible_unit_excursion_collision_m"] = "the run ended before the first lift-off"
    else:
        collision = _max_abs(traj.x_m[found[0].start : found[0].end])
    changes = []
    for i, window in enumerate(INSTANT_WINDOWS_S):
        change = math.nan if touchdown is None else x_change_after(traj, found[0].touchdown_s, window)
        if not math.isfinite(change):
            unavailable[f"x_change_after_touchdown_m[{i}]"] = (
                f"the run ended before {window * 1e3:g} ms after the first touchdown"
            )
        changes.append(change)
    rms = rms_height_error(traj, reference, ideal_landing.rebound_apex_s)
    if not math.isfinite(rms):
        unavailable["reference_rms_height_error_m"] = "the run ended before the apex of the reference's first rebound"
    free_fall = slice(0, touchdown if touchdown is not None else len(traj))
    unavailable = {name: reason for name, reason in unavailable.items() if name.split("[")[0] in _FIELDS}
    return RunMetrics(
        descent_accel_m_s2=measured,
        ideal_descent_accel_m_s2=ideal,
        compensation_error_pct=[100.0 * (a / a0 - 1.0) for a, a0 in zip(measured, ideal, strict=True)],
        residual_gravity_g=[(a - a0) / g for a, a0 in zip(measured, ideal, strict=True)],
        microgravity_level_g=[abs(a) / g for a in measured],
        accelerometer_descent_accel_m_s2=sensed,
        placement_delay_s=delays,
        flexible_unit_excursion_free_fall_m=_max_abs(traj.x_m[free_fall]),
        flexible_unit_excursion_collision_m=collision,
        x_change_after_touchdown_m=changes,
        support_force_variation_n=_max_abs(traj.support_force_deviation_n),
        servo_rms_torque_n_m=float(np.sqrt(np.mean(traj.servo_torque_n_m**2))),
        max_deformation_m=rig.max_deformation_m,
        collision_accel_m_s2=rig.collision_accel_m_s2,
        contact_time_s=rig.contact_time_s,
        restitution=rig.restitution,
        impact_speed_m_s=rig.impact_speed_m_s,
        rebound_height_m=rig.rebound_height_m,
        reference_max_deformation_m=ideal_landing.max_deformation_m,
        reference_collision_accel_m_s2=ideal_landing.collision_accel_m_s2,
        reference_contact_time_s=ideal_landing.contact_time_s,
        reference_restitution=ideal_landing.restitution,
        reference_rms_height_error_m=rms,
        termination_reason=traj.termination_reason,
        unavailable=unavailable,
    )


_FIELDS = frozenset(RunMetrics.__dataclass_fields__)
#: The metrics that measure a run: every field but the ideal descent (a closed form), the
#: termination reason and the reasons, and the residual gravity error (the compensation error
#: times a_ideal / g). Per-stage metrics are lists.
MEASURED_METRICS = tuple(
    name
    for name in RunMetrics.__dataclass_fields__
    if name not in {"ideal_descent_accel_m_s2", "residual_gravity_g", "termination_reason", "unavailable"}
)


def in_flight_weights(scenario) -> list[int]:
    """Indices (in ``scenario.loads``) of the weights placed in flight, at a height, not at t = 0."""
    return [i for i, load in enumerate(scenario.loads) if load.height_m is not None]


def placement_time(traj: Trajectory, weight: int) -> float:
    """When weight ``weight`` (an index of the schedule's loads) was placed, s: the first sample of
    its stage or a later one (weights placed together share the sample); NaN if never."""
    placed = np.flatnonzero(traj.stage >= weight)
    return float(traj.time_s[placed[0]]) if placed.size else math.nan


def x_change_after(traj: Trajectory, touchdown_s: float, window_s: float) -> float:
    """max |x(t) - x(touchdown)| over the samples in (touchdown, touchdown + window] (x at the
    touchdown interpolated between samples); NaN if the run ends before the window does."""
    t = traj.time_s
    if t[-1] < touchdown_s + window_s - 1e-12:
        return math.nan
    inside = (t > touchdown_s) & (t <= touchdown_s + window_s + 1e-12)
    return _max_abs(traj.x_m[inside] - float(np.interp(touchdown_s, t, traj.x_m)))


def rms_height_error(traj: Trajectory, reference: Trajectory, until_s: float) -> float:
    """RMS difference of foot heights from the start to ``until_s``; NaN if either run ends before it."""
    if not math.isfinite(until_s) or min(traj.time_s[-1], reference.time_s[-1]) < until_s:
        return math.nan
    keep = traj.time_s <= until_s
    reference_height = np.interp(traj.time_s[keep], reference.time_s, reference.foot_height_m)
    return float(np.sqrt(np.mean((traj.foot_height_m[keep] - reference_height) ** 2)))


def _max_abs(values: np.ndarray) -> float:
    return float(np.max(np.abs(values))) if values.size else math.nan
