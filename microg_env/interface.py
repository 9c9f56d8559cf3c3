"""The contract between the environment and its controllers: what an observation holds, what an
action means, and the spaces both are drawn from.

The environment (:mod:`microg_env.envs`) writes observations and reads actions; the controllers
(:mod:`microg_env.controllers`) read observations and write actions. Both import this module and
neither imports the other for it.

The controllers selectable by name (:data:`CONTROLLER_NAMES`: the baselines and the policies
shipped in ``microg_env/policies``) are found here without importing the controllers, so the
``microg`` command names them, and refuses a name that is neither, before the physics imports.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from gymnasium import spaces

from microg_env import validate
from microg_env.params import ScrewStageParams

#: The classical baselines (a residual action's base controllers; :mod:`microg_env.controllers`
#: builds them): the paper's PID, its derivative-on-measurement variant, the PID with
#: the nominal model's feed-forward, that feed-forward learning the motor's cogging as it runs
#: (``adaptive``), that with a dither on its setpoint against the friction (``adaptive-dither``),
#: that learning the friction's level too, with the pad force from the nominal pad where the rig
#: has no pad force sensor (``adaptive-friction``), and a reference point: the feed-forward told
#: the episode's true plant (``oracle``, not deployable).
BASELINES = ("pid", "pid-dom", "feedforward", "adaptive", "adaptive-dither", "adaptive-friction", "oracle")
#: Files of an exported policy folder: its network and its card (how it acts, how it was trained).
NETWORK_FILE, CARD_FILE = "policy.npz", "policy.json"


def shipped_policies() -> tuple[str, ...]:
    """Names of the policies shipped in the package (``microg_env/policies/<name>/``)."""
    root = resources.files("microg_env").joinpath("policies")
    if not root.is_dir():
        return ()
    return tuple(sorted(p.name for p in root.iterdir() if p.is_dir() and p.joinpath(CARD_FILE).is_file()))


#: Every controller selectable by name: the baselines and the shipped policies.
CONTROLLER_NAMES = BASELINES + shipped_policies()


def is_policy_folder(name: str) -> bool:
    """Whether ``name`` is the path of an exported policy folder (rather than a controller's name)."""
    return name not in CONTROLLER_NAMES and (Path(name) / CARD_FILE).is_file()


def selects_policy(name: str) -> bool:
    """Whether controller ``name`` is a policy (a shipped one, or the path of a policy folder)
    rather than a baseline; a ValueError listing the controllers where it is neither. Nothing is
    read: :func:`microg_env.controllers.registry.check_controller_name` checks a policy's folder."""
    if name in BASELINES:
        return False
    if name in CONTROLLER_NAMES or is_policy_folder(name):
        return True
    raise ValueError(
        f"controller must be one of {', '.join(CONTROLLER_NAMES)} or a policy folder (holding {CARD_FILE}), "
        f"got {name!r}"
    )


#: Observation entries and the scale each is divided by (SI units / scale = order one).
OBSERVATION_SCALES: dict[str, float] = {
    "x": 1e-4,  # grating ruler, m (100 um)
    "x_rate": 1e-3,  # its backward difference, m/s
    "support_position": 0.1,  # servo encoder, m above touchdown
    "support_velocity": 0.1,  # encoder backward difference, m/s
    "lander_accel": 0.1,  # accelerometer with g removed, m/s^2 (up positive)
    "pad_force": 100.0,  # pad force sensor, N
    "height": 0.1,  # foot height from encoder + ruler, m
    "placed_load": 1.0,  # test weights placed so far, kg
    "previous_action": 1.0,  # the agent's previous action
    # the base controller's speed command (residual mode; else 0), m/s: the paper's maximum speed
    "base_command": ScrewStageParams().max_speed_m_per_s,
}
OBSERVATION_INDEX = {name: i for i, name in enumerate(OBSERVATION_SCALES)}
SCALES = np.array(list(OBSERVATION_SCALES.values()))
#: The rig's sensor sets, by the observation entries each lacks (they read 0). ``extended``: every
#: sensor above; ``paper``: the paper's rig, which closes its loops on the grating ruler and the
#: servo encoder only (Section 4.1), with no pad force sensor and no accelerometer.
SENSOR_SETS: dict[str, tuple[str, ...]] = {"extended": (), "paper": ("lander_accel", "pad_force")}
#: The environment's ``sensor_set`` that draws each episode's set from SENSOR_SETS at its reset, with
#: equal odds (an engineering choice: no rig is favoured), so one training run meets both rigs and
#: its residual learns on the base controller as each rig's sensors leave it.
MIXED_SENSORS = "mixed"

#: Drive speed that the action +-1 stands for in the speed action mode, m/s: the paper's rig's
#: maximum (Section 4.1), a fixed unit of the action whatever rig is simulated (a slower drive
#: saturates on its own).
MAX_SPEED_M_S = ScrewStageParams().max_speed_m_per_s
#: The speeds that the speed action +-1 may stand for (the environment's ``speed_limit_m_s``), m/s:
#: from 1 mm/s, a few times the slowest descent's velocity error a period leaves, up to the drive's
#: MAX_SPEED_M_S (the default). A limit below the largest speed a task needs saturates there.
SPEED_LIMIT_RANGE_M_S = (1e-3, MAX_SPEED_M_S)
#: What an action is: the drive's speed reference (``speed``), an x setpoint on a base
#: controller (``residual``), or the gains of a base PID (``gains``).
ACTION_MODES = ("speed", "residual", "gains")
#: The base controllers whose gains a ``gains`` action schedules: the PIDs (Section 3.1).
GAIN_BASES = ("pid", "pid-dom")
#: The gains a ``gains`` action multiplies, one action component each, in this order.
SCHEDULED_GAINS = ("kp_per_s", "ki_per_s2", "kd")
#: The multiplier that the action +-1 stands for in the ``gains`` action mode (the environment's
#: ``gain_limit``): a component a multiplies its gain by gain_limit ** a. 2 by default, the gain
#: margin the PIDs were tuned to on the nominal rig (config/controllers.toml); on a drawn plant
#: every gain doubled at once can be unstable (docs/environment.md, "Gain actions"), so the task
#: holds schedules the learner must avoid. At most 10.
GAIN_LIMIT, MAX_GAIN_LIMIT = 2.0, 10.0
#: The reward's descent term (the environment's ``reward_descent_weight``): the velocity error of
#: each stage's descent against the ideal m g / (M + m) from the descent fit's start on
#: (:func:`~microg_env.envs.period.score_descent`), scored in decades as x is, from
#: ``reward_descent_scale_m_s`` (by default DESCENT_SCALE_M_S: about the scatter the lander's
#: vibration leaves in one period's error, 2-6e-8 m/s measured with ``adaptive`` on training draws)
#: to DESCENT_LIMIT_M_S (five decades up; x's reward spans 6.4, 10 nm to 24.9 mm), where it
#: scores 0 (and below, beyond it).
DESCENT_SCALE_M_S, DESCENT_LIMIT_M_S = 1e-7, 1e-2
#: The x setpoint that the action +-1 stands for in the residual action mode, m (the default of
#: the environment's ``residual_limit_m``).
RESIDUAL_LIMIT_M = 1e-6
#: The corner of the residual's high-pass in ``MicroGravityLanding-Residual-v6`` and -v7, Hz. Its time
#: constant, 1/(2 pi 2 Hz) = 80 ms, lets a held residual decay by e^-2.5 within the 0.2 s that
#: the descent fit waits after a weight is placed (scenarios.SETTLE_S), so the residual
#: shapes transients while the base controller keeps the steady state; it is the corner
#: ``adaptive`` high-passes its cogging error at too.
RESIDUAL_HIGHPASS_HZ = 2.0
#: The orders a residual's high-pass may take: 1, a held action decays to 0; 2 (two first-order
#: stages in cascade), a steadily changing one too. Through one stage an action ramping at r per
#: second leaves a setpoint of r tau limit: v2's shipped policy ramped about 0.04 per second through
#: each free fall (its observations drift as the lander falls) and held x +6 nm off on condition 1,
#: with 0.0196 % of compensation error against adaptive's -0.0009 % (docs/research-log.md).
RESIDUAL_HIGHPASS_ORDERS = (1, 2)  # the lowest and highest
#: The corners a residual's high-pass may take, Hz (0: none; the drive's 100 Hz speed loop, above
#: which nothing of the residual would pass that the drive follows).
RESIDUAL_HIGHPASS_RANGE_HZ = (0.0, 100.0)

#: The foot heights at or below which a gated residual acts (the environment's
#: ``residual_gate_m``), m: from the pad's surface (the contact alone) to 0.1 m, above the paper's
#: and training's starts (such a gate never closes before the pad).
RESIDUAL_GATE_RANGE_M = (0.0, 0.1)
#: What a residual's gate passes (the environment's ``residual_gate_on``): the agent's ``action``,
#: then high-passed, so an action held before the gate opens passes it as a step; or the high-passed
#: ``setpoint``, the action filtered throughout, so a held one has decayed by the time the gate
#: opens and only what the action changes passes.
RESIDUAL_GATE_POINTS = ("action", "setpoint")


def hidden_entries(names: object) -> tuple[str, ...]:
    """Observation entries an agent is shown as 0 (``hidden_observations``): distinct names of
    :data:`OBSERVATION_SCALES`, as a tuple, or a FieldError naming the bad one."""
    field = "hidden_observations"
    if isinstance(names, str) or not isinstance(names, list | tuple):
        raise validate.FieldError(f"{field} must be a list of observation entries, got {validate.shown(names)}", field)
    for i, name in enumerate(names):
        if not isinstance(name, str) or name not in OBSERVATION_INDEX:
            raise validate.FieldError(
                f"{field}[{i}] must be one of {', '.join(OBSERVATION_INDEX)}, got {validate.shown(name)}", field
            )
        if name in names[:i]:
            raise validate.FieldError(f"{field}[{i}]: {name!r} is given twice", field)
    return tuple(names)


def highpass_order(order: object) -> int:
    """A residual high-pass's order (:data:`RESIDUAL_HIGHPASS_ORDERS`), or a FieldError naming it."""
    return validate.integer("residual_highpass_order", order, *RESIDUAL_HIGHPASS_ORDERS)


def highpass_gain(corner_hz: float, period_s: float) -> float | None:
    """The gain a = tau / (tau + T) of a first-order high-pass with corner ``corner_hz`` sampled
    every ``period_s`` (tau = 1 / (2 pi corner)); None for a corner of 0 (no filter)."""
    if corner_hz == 0.0:
        return None
    tau = 1.0 / (2.0 * np.pi * corner_hz)
    return tau / (tau + period_s)


def residual_setpoint(
    actions: np.ndarray,
    ids: np.ndarray,
    limit_m: float,
    gain: float | None,
    last_action: np.ndarray,
    last_setpoint_m: np.ndarray,
    last_stage_m: np.ndarray | None = None,
) -> np.ndarray:
    """The x setpoints (m) that residual ``actions`` of rigs ``ids`` stand for: ``action *
    limit_m``, or with a high-pass ``gain`` (:func:`highpass_gain`) that passed through the filter
    y_n = a (y_(n-1) + (u_n - u_(n-1)) limit), whose state per rig is ``last_action`` (u) and
    ``last_setpoint_m`` (y), both 0 when an episode starts: a held action decays to a zero
    setpoint, so a residual cannot move the steady state its base controller holds. With
    ``last_stage_m`` (the first stage's last output, 0 at the start) the second-order cascade:
    the first stage's output w goes through a second, y_n = a (y_(n-1) + w_n - w_(n-1)), so an
    action changing at a steady rate decays to a zero setpoint as well."""
    if gain is None:
        return actions * limit_m
    stage = gain * (
        (last_setpoint_m if last_stage_m is None else last_stage_m)[ids] + (actions - last_action[ids]) * limit_m
    )
    last_action[ids] = actions
    if last_stage_m is None:
        last_setpoint_m[ids] = stage
        return stage
    setpoint = gain * (last_setpoint_m[ids] + stage - last_stage_m[ids])
    last_stage_m[ids] = stage
    last_setpoint_m[ids] = setpoint
    return setpoint


def residual_gate_point(stage: object) -> str:
    """What a residual's gate passes (:data:`RESIDUAL_GATE_POINTS`), or a FieldError naming it."""
    return validate.choice("residual_gate_on", stage, RESIDUAL_GATE_POINTS)


def gated_setpoint(
    actions: np.ndarray,
    observations: np.ndarray,
    ids: np.ndarray,
    gate_m: float | None,
    gate_on: str,
    limit_m: float,
    gain: float | None,
    filter_state: tuple[np.ndarray, np.ndarray, np.ndarray | None],
) -> np.ndarray:
    """The x setpoints (m) of residual ``actions`` of rigs ``ids`` through the gate at ``gate_m``
    (:func:`gated_actions`, on what ``gate_on`` names) and the high-pass (:func:`residual_setpoint`,
    whose per-rig ``filter_state`` is its last input, last output and first stage's last output)."""
    if gate_on == "setpoint":
        return gated_actions(residual_setpoint(actions, ids, limit_m, gain, *filter_state), observations, gate_m)
    if gate_on == "action":
        return residual_setpoint(gated_actions(actions, observations, gate_m), ids, limit_m, gain, *filter_state)
    raise ValueError(f"gate_on must be one of {', '.join(map(repr, RESIDUAL_GATE_POINTS))}, got {gate_on!r}")


def residual_gate(gate_m: object) -> float | None:
    """A residual's gate height (:data:`RESIDUAL_GATE_RANGE_M`; None: no gate), or a FieldError
    naming it."""
    return None if gate_m is None else validate.between("residual_gate_m", gate_m, *RESIDUAL_GATE_RANGE_M, "m")


def gated_actions(actions: np.ndarray, observations: np.ndarray, gate_m: float | None) -> np.ndarray:
    """Residual ``actions`` (or setpoints, (n,)) or gains actions ((n, 3)) as a gate at foot height
    ``gate_m`` passes them: each rig's value while its foot reads at most ``gate_m`` above the pad
    (``observations``' height entry: the servo encoder and the grating ruler, a reading of the
    paper's rig as well), else 0, so that the base controller alone (as tuned) flies the descent
    above it; ``actions`` themselves without a gate. The gate is compared in the observation's own
    float32 units (whatever array holds the readings), so a foot exactly at the gate reads at it."""
    if gate_m is None:
        return actions
    heights = np.asarray(observations[:, OBSERVATION_INDEX["height"]], dtype=np.float32)
    passes = heights <= np.float32(gate_m / OBSERVATION_SCALES["height"])
    return np.where(passes[:, None] if np.ndim(actions) == 2 else passes, actions, 0.0)


def action_size(action_mode: str) -> int:
    """How many numbers one rig's action holds: a gain per :data:`SCHEDULED_GAINS` in ``gains``
    mode, else one (the drive's speed reference or the residual x setpoint)."""
    return len(SCHEDULED_GAINS) if action_mode == "gains" else 1


def action_space(action_mode: str = "speed") -> spaces.Box:
    """One rig's action in ``action_mode``, in [-1, 1] (:func:`action_size` numbers, units above)."""
    return spaces.Box(-1.0, 1.0, shape=(action_size(action_mode),), dtype=np.float32)


def speed_actions(actions: np.ndarray, limit_m_s: float) -> np.ndarray:
    """The drive's actions (the speed over :data:`MAX_SPEED_M_S`) that speed actions in [-1, 1]
    stand for at ``speed_limit_m_s`` ``limit_m_s``: ``actions * (limit / MAX_SPEED_M_S)`` as
    float32, the type a controller returns, so that the environment commands what a policy's
    controller does, bit for bit; at the default limit a float32 action is itself."""
    return np.asarray(actions * (limit_m_s / MAX_SPEED_M_S), dtype=np.float32)


def speed_commands_m_s(actions: np.ndarray, limit_m_s: float) -> np.ndarray:
    """The drive's speed commands (m/s, float64) that speed actions stand for at ``speed_limit_m_s``
    ``limit_m_s``: at the default limit the action times :data:`MAX_SPEED_M_S`; below it
    :func:`speed_actions` (what a controller returns) times :data:`MAX_SPEED_M_S`."""
    actions = np.asarray(actions, dtype=np.float64)
    if limit_m_s == MAX_SPEED_M_S:
        return actions * MAX_SPEED_M_S
    return speed_actions(actions, limit_m_s).astype(np.float64) * MAX_SPEED_M_S


def gain_scales(actions: np.ndarray, limit: float) -> np.ndarray:
    """The gain multipliers that ``gains`` actions (n, 3) in [-1, 1] stand for: ``limit ** action``,
    so an action of 0 is exactly the base PID (a multiplier of exactly 1)."""
    return np.power(limit, np.asarray(actions, dtype=np.float64))


def observation_space() -> spaces.Box:
    """One rig's observation: :data:`OBSERVATION_SCALES`'s entries, each divided by its scale."""
    return spaces.Box(-np.inf, np.inf, shape=(len(SCALES),), dtype=np.float32)


@dataclass(frozen=True)
class Readings:
    """Observations (n, 10) in SI units (OBSERVATION_SCALES), one (n,) array per reading."""

    x_m: np.ndarray  # grating ruler
    x_rate_m_s: np.ndarray
    support_position_m: np.ndarray  # servo encoder, above touchdown
    support_velocity_m_s: np.ndarray
    lander_accel_m_s2: np.ndarray  # accelerometer, g removed, up positive
    pad_force_n: np.ndarray
    foot_height_m: np.ndarray
    placed_load_kg: np.ndarray

    @classmethod
    def of(cls, observations: np.ndarray) -> Readings:
        si = observations * SCALES  # float64

        def get(name: str) -> np.ndarray:
            return si[:, OBSERVATION_INDEX[name]]

        return cls(
            get("x"),
            get("x_rate"),
            get("support_position"),
            get("support_velocity"),
            get("lander_accel"),
            get("pad_force"),
            get("height"),
            get("placed_load"),
        )
