"""Parameters -> MuJoCo model: the rig of ``assets/scene.xml`` with every force law from params.

:func:`build_rig` loads the MJCF template with :class:`mujoco.MjSpec`, writes every physical value
of :class:`~microg_env.params.RigParams` into it (masses, geometry, springs, friction, servo drive,
pad contact), gives it one body per test weight and compiles. :class:`Rig` holds the compiled model,
the addresses a simulation needs, and :meth:`Rig.episode_fields`: the model field values that
change from episode to episode (the test weights placed, the balancer's trim, a randomised lander,
pad or friction). They are written into the one model of a single rig, or per simulation into a
``mujoco.batch.Batch``, so nothing is recompiled at a reset. :func:`pad_contact_solref` turns the
pad's K and D into MuJoCo's ``solref``/``solimp``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from microg_env import validate
from microg_env.compiled import ufunc
from microg_env.params import PHYSICS_STEP_RANGE_S, PHYSICS_STEP_S, RigParams, parameter_paths
from microg_env.sim.limits import check_integrable, validate_loads
from microg_env.sim.physics import FieldWrite
from microg_env.validate import FieldError

#: Density of the steel test weights (for their size only; their mass is what matters).
_STEEL_DENSITY_KG_M3 = 7850.0
#: Template load bodies in rig.xml (the paper's weights, Table 2); build_rig replaces them.
TEMPLATE_LOADS = {"load_50g": 0.05, "load_490g": 0.49, "load_1kg": 1.0}
#: The foot's collision cylinder reaches this far above the pad's full depth, m, so that only its
#: sole ever touches the pad, at any deformation the pad allows.
_FOOT_COLLISION_MARGIN_M = 0.01
#: Linear damping of the ideal drive's speed source, N s/m at the support: the largest load the
#: screw meets (~6.5 kN) leaves a speed error of 6.5 nm/s. Implicit in MuJoCo's ``implicitfast``
#: integrator, so it neither lags nor chatters at any physics step.
IDEAL_DRIVE_DAMPING_N_S_PER_M = 1.0e12
#: The motor's coordinate of a compliant transmission (its angle over the gear, m of support travel).
MOTOR_JOINT = "motor"
#: Mass of the motor joint's body, kg: a token MuJoCo needs for a moving body (the motor side's
#: inertia is the servo's armature, ~200 kg at the support).
_MOTOR_BODY_MASS_KG = 1e-6
#: Index of the dcmotor's setpoint slew rate (rad/s) in ``actuator_dynprm``.
SLEW_PARAMETER = 7
#: How the drive meets the mechanics in each physics step (``TaskSettings.drive_scheme``).
#: ``"mujoco"``: MuJoCo's own ``dcmotor`` stepping: the current at the step's end drives the step
#: (``actearly``), the speed loop compares the reference at the step's end with the angle at its
#: start and reads the speed of the step before, under ``implicitfast``; sub-micrometre excursions
#: are first order in the step (docs/model.md, "Drive scheme"). ``"midpoint"``: the current at the
#: step's start drives it, and the speed loop reads the reference, angle and speed at the middle of
#: the step its current is filtered over (:func:`microg_env.envs.period.speed_inputs`, every physics
#: step), under MuJoCo's ``euler`` integrator, whose implicit part is the joints' damping only
#: (``implicitfast`` also takes the friction's bristle damping as acting in sliding, where it does
#: not). The ideal drive is the same under both.
DRIVE_SCHEMES = ("mujoco", "midpoint")
#: The environment's drive scheme (converged). :func:`build_rig` keeps ``"mujoco"`` by default: a rig
#: built on its own is stepped with ``mujoco.mj_step``, which the midpoint drive cannot be.
DEFAULT_DRIVE_SCHEME = "midpoint"
#: Slew rate standing for a zero speed reference (a zero rate would switch the slew limiter off).
MIN_SLEW_RAD_S = 1e-12


@ufunc("float64(float64)")
def slew_rate(speed_ref_rad_s: float) -> float:
    """The dcmotor's setpoint slew rate that ramps its reference at ``speed_ref_rad_s``, rad/s (a
    NumPy ufunc, also called from the compiled control period)."""
    return max(abs(speed_ref_rad_s), MIN_SLEW_RAD_S)


#: Where MuJoCo's ``dcmotor`` keeps the parameters an episode may change: (field, index) of
#: ``actuator_gainprm`` (kp, kd of the on-board controller), ``actuator_biasprm`` (cogging amplitude
#: and phase, the torque being A sin(N theta + phase); LuGre Coulomb, static torque and Stribeck
#: speed) and ``actuator_dynprm`` (current time constant; LuGre bristle stiffness and damping).
DCMOTOR_FIELDS = {
    "kp": 4,
    "kd": 6,
    "cogging": 0,
    "cogging_phase": 2,
    "coulomb": 3,
    "static": 4,
    "stribeck": 5,
    "torque_filter": 0,
    "bristle_stiffness": 5,
    "bristle_damping": 6,
}
#: Parameters that :meth:`Rig.episode_fields` can change without recompiling the model.
EPISODE_PARAMETERS = frozenset(
    {
        "lander.mass_kg",
        "pad.stiffness_n_per_m",
        "pad.damping_n_s_per_m",
        "qzs.guide_friction_n",
        "qzs.guide_static_friction_n",
        "qzs.guide_damping_n_s_per_m",
        "servo.coulomb_torque_n_m",
        "servo.static_torque_n_m",
        "servo.stribeck_speed_rad_s",
        "servo.bristle_stiffness_n_m_per_rad",
        "servo.bristle_damping_n_m_s_per_rad",
        "servo.cogging_torque_n_m",
        "servo.cogging_phase_rad",
        "servo.speed_loop_gain_hz",
        "servo.torque_filter_s",
    }
)


def mjcf_dir() -> Path:
    """The package's folder of MJCF files (``microg_env/assets``: scene.xml includes rig.xml)."""
    return Path(__file__).resolve().parents[1] / "assets"


def pad_contact_solref(
    stiffness_n_per_m: float,
    damping_n_s_per_m: float,
    mass_kg: float,
    n_contacts: int,
    impedance: float,
) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo ``solref`` and ``solimp`` that make n contact points act as one spring-damper (K, D).

    With constant impedance d (``solimp = d d ...``) and the direct format ``solref = (-s, -b)``,
    MuJoCo uses per contact row the reference acceleration -(s r + b r')/d and the regulariser
    R = A (1-d)/d, where A = 1/m is the exact inverse mass the row sees (``diagexact``; m is the
    lander with its loads). Solving the n identical rows together gives
        m a = [(1-d) F_other - n m (s r + b r')] / (1 + (n-1) d),
    with r the penetration (negative) and F_other every other force on the lander. Choosing
        s = K (1 + (n-1) d) / (n m),   b = D (1 + (n-1) d) / (n m)
    gives m a = (1 - d) / (1 + (n-1) d) F_other - K r - D r': the impact is exactly Eq. (1), and
    every other force during contact is scaled by ~1 - n d (0.9997 for d = 1e-4, n = 3), so the
    static sink under a load F is F/K to 3e-4.
    """
    validate.positive("pad stiffness", stiffness_n_per_m, "N/m")
    validate.positive("pad damping", damping_n_s_per_m, "N s/m")
    validate.positive("mass", mass_kg, "kg")
    validate.integer("n_contacts", n_contacts, 1)
    scale = (1.0 + (n_contacts - 1) * impedance) / (n_contacts * mass_kg)
    solref = np.array([-stiffness_n_per_m * scale, -damping_n_s_per_m * scale])
    solimp = np.array([impedance, impedance, 0.001, 0.5, 2.0])
    return solref, solimp


@dataclass(frozen=True)
class FlexibleUnit:
    """QZS mechanism and nitrogen balancer, balanced to carry the lander at x = 0."""

    qzs_force_n: float  # QZS force on the lander at x = 0
    balancer_force_n: float  # the balancer's force at its trim point
    balancer_stiffness_n_per_m: float  # k = n F A / V
    #: Support force lost per metre of x: the QZS's residual stiffness (Eq. 17), plus the
    #: balancer's when it acts in parallel with the QZS. Negative for Eq. 17's literal reading.
    x_stiffness_n_per_m: float
    #: Static load on the screw at the balancer's trim point (lander and support weight, minus
    #: the balancer's force when it acts between frame and support), N.
    screw_load_n: float


def flexible_unit(params: RigParams) -> FlexibleUnit:
    """Forces and stiffnesses of the flexible unit for ``params`` (see BalancerParams.placement)."""
    qzs, g = params.qzs, params.gravity_m_s2
    lander_weight = params.lander.mass_kg * g
    carried_weight = (params.lander.mass_kg + params.screw.support_mass_kg) * g
    if params.balancer.placement == "frame_support":
        balancer_force = carried_weight
        qzs_force = lander_weight
        stiffness = params.balancer.stiffness_n_per_m(balancer_force)
        return FlexibleUnit(qzs_force, balancer_force, stiffness, qzs.residual_stiffness_n_per_m, 0.0)
    qzs_force = qzs.weight_share * lander_weight
    balancer_force = lander_weight - qzs_force
    stiffness = params.balancer.stiffness_n_per_m(balancer_force)
    return FlexibleUnit(
        qzs_force, balancer_force, stiffness, qzs.residual_stiffness_n_per_m + stiffness, carried_weight
    )


def servo_max_speed_rad_s(params: RigParams) -> float:
    """The motor's speed at the mechanism's maximum vertical speed, rad/s (Section 4.1)."""
    return params.screw.max_speed_m_per_s * params.screw.gear_rad_per_m


def drive_inertia_kg_m2(params: RigParams) -> float:
    """The inertia the drive moves, at the motor: rotor, screw and the floating support reflected
    through the screw (the lander hangs on the 1.2 Hz QZS spring, far below the speed loop's
    bandwidth, so the loop does not feel it), kg m^2."""
    screw = params.screw
    return (
        params.servo.rotor_inertia_kg_m2 + screw.screw_inertia_kg_m2 + screw.support_mass_kg / screw.gear_rad_per_m**2
    )


def speed_loop_gains(params: RigParams) -> tuple[float, float]:
    """The drive's PI speed loop as dcmotor gains (kp, kd), N m/rad and N m s/rad: kd = Kv J and
    kp = Kv J / Ti, with J :func:`drive_inertia_kg_m2`."""
    servo = params.servo
    kd = 2.0 * math.pi * servo.speed_loop_gain_hz * drive_inertia_kg_m2(params)
    return kd / servo.speed_integral_time_s, kd


class Rig:
    """A compiled rig model, the addresses a simulation needs, and its per-episode field values.

    A test weight that is not yet placed is held off the lander (by the experimenter's hand): it
    has no mass in the model, so it neither weighs on the lander nor adds to its inertia. Placing
    it gives it its mass and retunes the pad contact to the new total mass. :meth:`episode_fields`
    and :meth:`start_state` are the one source of an episode's model values and start; the rig core
    (:mod:`microg_env.envs.core`) writes them for one rig or per simulation of a batch, and
    :meth:`reset`, :meth:`place_loads` and :meth:`trim_balancer` write them into ``model`` for
    scripts that step one ``MjData`` by hand.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        params: RigParams,
        loads_kg: tuple[float, ...],
        pad_contacts: int,
        ideal_drive: bool,
        midpoint_drive: bool = False,
    ) -> None:
        self.model = model
        self.params = params
        self.loads_kg = loads_kg
        self.pad_contacts = pad_contacts
        self.ideal_drive = ideal_drive
        screw, qzs = model.joint("screw").id, model.joint("qzs").id
        self.screw_qpos = int(model.jnt_qposadr[screw])
        self.qzs_qpos = int(model.jnt_qposadr[qzs])
        self.screw_dof = int(model.jnt_dofadr[screw])
        self.qzs_dof = int(model.jnt_dofadr[qzs])
        self.gear = params.screw.gear_rad_per_m  # motor radians per metre of support travel
        motor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, MOTOR_JOINT)  # -1: a rigid transmission
        #: The motor's coordinate (m of support travel) in ``qpos``, which the encoder reads: the
        #: screw's on a rigid transmission.
        self.motor_qpos = self.screw_qpos if motor < 0 else int(model.jnt_qposadr[motor])
        self.motor_dof = self.screw_dof if motor < 0 else int(model.jnt_dofadr[motor])
        #: Whether the speed loop's inputs are set every physics step (``drive_scheme="midpoint"``).
        self.midpoint_drive = midpoint_drive
        self.lander_body = model.body("lander").id
        self.load_bodies = np.array([model.body(f"load_{i}").id for i in range(len(loads_kg))], dtype=int)
        self._load_geoms = np.array([model.geom(f"load_{i}").id for i in range(len(loads_kg))], dtype=int)
        self._unit_load_inertia = model.body_inertia[self.load_bodies] / np.array(loads_kg)[:, None]
        self._pad_geom = model.geom("pad").id
        self._balancer = model.tendon("balancer").id
        self.servo = model.actuator("servo").id
        self._guide = model.actuator("guide_friction").id
        #: Index of the drive's interpolated position reference (its slew state) in ``data.act``.
        self.reference_act = int(model.actuator_actadr[self.servo])
        #: Index of the drive current (the torque filter's state) in ``data.act``, or None.
        self.current_act = int(model.actuator_actadr[self.servo] + model.actuator_actnum[self.servo] - 1)
        if ideal_drive or params.servo.torque_filter_s == 0:
            self.current_act = None
        self._motor_lugre = not ideal_drive and params.servo.bristle_stiffness_n_m_per_rad > 0
        self._guide_lugre = params.qzs.guide_friction_n > 0
        self.placed = np.ones(len(loads_kg), dtype=bool)  # as compiled: every weight on the lander
        self.placed_load_kg = float(sum(loads_kg))  # total of the weights on the lander, kg
        self.trim_height_m = 0.0

    # -- per-episode field values ----------------------------------------------------------

    def episode_fields(
        self, params: RigParams, loads_kg: tuple[float, ...], placed: np.ndarray, trim_height_m: float
    ) -> list[FieldWrite]:
        """Model field values for ``params``, these test weights (``placed`` on the lander) and a
        balancer trimmed at support height ``trim_height_m``; ``params`` may differ from the
        built rig's only in :data:`EPISODE_PARAMETERS`. A schedule with fewer weights than the rig
        has bodies for leaves the others off (a batch of rigs runs schedules of different lengths)."""
        self.check_episode_params(params)
        count = len(self.load_bodies)
        if len(loads_kg) > count:
            raise ValueError(f"the rig has {count} test weights, got {len(loads_kg)}")
        validate_loads(tuple(loads_kg), params.lander.mass_kg)
        loads = np.zeros(count)
        loads[: len(loads_kg)] = loads_kg
        placed = np.asarray(placed, dtype=bool)
        lander_mass = params.lander.mass_kg
        carried = lander_mass + float(np.dot(loads, placed))
        unit = flexible_unit(params)
        pad = params.pad
        solref, _ = pad_contact_solref(
            pad.stiffness_n_per_m, pad.damping_n_s_per_m, carried, self.pad_contacts, pad.impedance
        )
        trim_length = unit.balancer_force_n / unit.balancer_stiffness_n_per_m
        if params.balancer.placement == "frame_support":
            trim_length += trim_height_m  # the balancer's length is the support's height
        writes: list[FieldWrite] = [
            ("body_mass", self.lander_body, lander_mass),
            ("body_mass", self.load_bodies, np.where(placed, loads, 0.0)),
            (
                "body_inertia",
                self.load_bodies,
                np.where(placed[:, None], loads[:, None] * self._unit_load_inertia, 0.0),
            ),
            # held weights drawn faint, those beyond the schedule's not at all
            ("geom_rgba", (self._load_geoms, 3), np.where(placed, 1.0, np.where(loads > 0.0, 0.25, 0.0))),
            ("geom_solref", self._pad_geom, solref),
            ("qpos_spring", self.qzs_qpos, unit.qzs_force_n / params.qzs.residual_stiffness_n_per_m),
            ("tendon_stiffness", self._balancer, unit.balancer_stiffness_n_per_m),
            ("tendon_lengthspring", self._balancer, np.array([trim_length, trim_length])),
            ("dof_damping", self.qzs_dof, params.qzs.guide_damping_n_s_per_m),
        ]
        servo, motor = params.servo, self.servo
        if not self.ideal_drive:  # the dcmotor's parameters (DCMOTOR_FIELDS)
            kp, kd = speed_loop_gains(params)
            writes += [
                ("actuator_gainprm", (motor, DCMOTOR_FIELDS["kp"]), kp),
                ("actuator_gainprm", (motor, DCMOTOR_FIELDS["kd"]), kd),
                ("actuator_biasprm", (motor, DCMOTOR_FIELDS["cogging"]), servo.cogging_torque_n_m),
                ("actuator_biasprm", (motor, DCMOTOR_FIELDS["cogging_phase"]), servo.cogging_phase_rad),
            ]
            if self.current_act is not None:
                writes.append(("actuator_dynprm", (motor, DCMOTOR_FIELDS["torque_filter"]), servo.torque_filter_s))
        if self._motor_lugre:
            writes += [
                ("actuator_biasprm", (motor, DCMOTOR_FIELDS["coulomb"]), servo.coulomb_torque_n_m),
                ("actuator_biasprm", (motor, DCMOTOR_FIELDS["static"]), servo.static_torque_n_m),
                ("actuator_biasprm", (motor, DCMOTOR_FIELDS["stribeck"]), servo.stribeck_speed_rad_s),
                ("actuator_dynprm", (motor, DCMOTOR_FIELDS["bristle_stiffness"]), servo.bristle_stiffness_n_m_per_rad),
                ("actuator_dynprm", (motor, DCMOTOR_FIELDS["bristle_damping"]), servo.bristle_damping_n_m_s_per_rad),
            ]
        if self._guide_lugre:
            writes.append(("actuator_biasprm", (self._guide, 3), params.qzs.guide_friction_n))
            writes.append(("actuator_biasprm", (self._guide, 4), params.qzs.guide_static_friction_n))
        return writes

    def check_episode_params(self, params: RigParams) -> None:
        """Raise ValueError if ``params`` differs from the built rig's beyond :data:`EPISODE_PARAMETERS`,
        or sets one of them to or from the 0 that removes a model state (:func:`model_states`)."""
        built, given = parameter_paths(self.params), parameter_paths(params)
        changed = sorted(path for path in built if built[path] != given[path] and path not in EPISODE_PARAMETERS)
        states = zip(MODEL_STATES, model_states(self.params), model_states(params), strict=True)
        changed += [f"{path} (to or from 0, which adds or removes a model state)" for path, a, b in states if a != b]
        if changed:
            raise ValueError(f"parameters {', '.join(changed)} differ from the built rig's: build a new rig")

    def write(self, writes: list[FieldWrite]) -> None:
        """Write field values into this rig's model."""
        for name, index, value in writes:
            getattr(self.model, name)[index] = value

    def place_loads(self, placed: np.ndarray | list[bool]) -> None:
        """Put each test weight on the lander (True) or hold it off (False)."""
        placed = np.asarray(placed, dtype=bool)
        if placed.shape != self.placed.shape:
            raise ValueError(f"placed must have one entry per load ({self.placed.size}), got shape {placed.shape}")
        self.write(self.episode_fields(self.params, self.loads_kg, placed, self.trim_height_m))
        self.placed = placed.copy()
        self.placed_load_kg = float(np.dot(self.loads_kg, placed)) if self.loads_kg else 0.0

    def trim_balancer(self, support_height_m: float) -> None:
        """Balance the rig at this support height (Section 4.1: balanced before each test)."""
        self.trim_height_m = float(support_height_m)
        self.write(self.episode_fields(self.params, self.loads_kg, self.placed, self.trim_height_m))

    # -- state --------------------------------------------------------------------------------

    def foot_height(self, data: mujoco.MjData) -> float:
        """Height of the foot's sole above the undeformed pad, m (negative: deforming the pad)."""
        return float(data.qpos[self.screw_qpos] + data.qpos[self.qzs_qpos])

    def reset(self, data: mujoco.MjData, height_m: float) -> None:
        """Balanced rest: foot ``height_m`` above the pad, x = 0, servo holding, no weight placed."""
        self.place_loads(np.zeros(len(self.loads_kg), dtype=bool))
        self.trim_balancer(height_m)
        mujoco.mj_resetData(self.model, data)
        for name, index, value in self.start_state(self.params, height_m):
            getattr(data, name)[index] = value
        mujoco.mj_forward(self.model, data)

    def start_state(self, params: RigParams, height_m: float) -> list[tuple[str, int, float]]:
        """The state writes, (MjData field, index, value), after a reset to the model's defaults,
        that give balanced rest with the foot ``height_m`` above the pad, x = 0, the servo holding."""
        writes = [("qpos", self.screw_qpos, height_m)]
        if self.ideal_drive:
            return [*writes, ("ctrl", 0, 0.0)]
        motor_m = height_m + transmission_deflection_m(params)  # the transmission's spring carries the load
        if self.motor_qpos != self.screw_qpos:
            writes.append(("qpos", self.motor_qpos, motor_m))
        # The speed loop's position term holds the screw's static load with a small lag.
        load = flexible_unit(params).screw_load_n
        kp, _ = speed_loop_gains(params)
        reference = motor_m * self.gear + load / (self.gear * kp)
        writes += [("ctrl", 0, reference), ("ctrl", 1, 0.0), ("act", self.reference_act, reference)]
        if self.current_act is not None:  # the torque filter starts settled on that load
            writes.append(("act", self.current_act, load / self.gear / params.servo.torque_constant_n_m_per_a))
        return writes

    def drive(self, data: mujoco.MjData, position_ref_rad: float, speed_ref_rad_s: float, steps: int) -> float:
        """Step ``steps`` physics steps at a constant speed reference; returns the position
        reference reached at their end.

        The real drive interpolates its position reference from ``position_ref_rad`` as a ramp at
        the commanded speed (Section 4.1's servo receives a speed command every control period).
        The dcmotor's setpoint slew limiter realises that ramp inside MuJoCo: the setpoint is the
        period's end and the slew rate the commanded speed, so the reference moves by exactly
        speed x step in every physics step (it reads the end of each step, where a first-order
        integrator's force is held over the step).
        """
        if self.midpoint_drive:
            raise ValueError("Rig.drive steps MuJoCo's own dcmotor inputs; a midpoint drive is stepped by LandingCore")
        model, ctrl, dt = self.model, data.ctrl, self.model.opt.timestep
        end = position_ref_rad + speed_ref_rad_s * dt * steps
        if self.ideal_drive:
            ctrl[0] = speed_ref_rad_s
        else:
            model.actuator_dynprm[self.servo, SLEW_PARAMETER] = slew_rate(speed_ref_rad_s)
            ctrl[0], ctrl[1] = end, speed_ref_rad_s
        mujoco.mj_step(model, data, nstep=steps)
        return end


#: The episode parameters whose 0 removes a state from the compiled model, in the order of
#: :func:`model_states`: the drive's current (torque filter), the guide's and the motor's bristles.
MODEL_STATES = ("servo.torque_filter_s", "qzs.guide_friction_n", "servo.bristle_stiffness_n_m_per_rad")


def model_states(params: RigParams) -> tuple[bool, ...]:
    """Which of the :data:`MODEL_STATES` the model of ``params`` compiles (a parameter above 0)."""
    paths = parameter_paths(params)
    return tuple(paths[path] > 0 for path in MODEL_STATES)


def _load_geometry(mass_kg: float) -> tuple[float, float]:
    """Radius and half-height of a steel cylinder of height 1.5 x radius with this mass."""
    radius = (mass_kg / (_STEEL_DENSITY_KG_M3 * math.pi * 1.5)) ** (1.0 / 3.0)
    return radius, 0.75 * radius


def _apply_geometry_and_masses(spec: mujoco.MjSpec, params: RigParams, physics_step_s: float) -> None:
    lander, pad, screw = params.lander, params.pad, params.screw
    spec.option.timestep = physics_step_s
    spec.option.gravity = (0.0, 0.0, -params.gravity_m_s2)
    spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_DIAGEXACT
    spec.body("lander").mass = lander.mass_kg
    spec.body("floating_support").mass = screw.support_mass_kg
    # The collision foot reaches above the pad's full depth so that only its sole touches the pad.
    reach = pad.thickness_m + _FOOT_COLLISION_MARGIN_M
    foot = spec.geom("foot")
    foot.size = (lander.foot_radius_m, reach / 2.0, 0.0)
    foot.pos = (0.0, 0.0, reach / 2.0)
    plate = spec.geom("foot_plate")
    plate.size = (lander.foot_radius_m, lander.foot_height_m / 2.0, 0.0)
    plate.pos = (0.0, 0.0, lander.foot_height_m / 2.0)
    spec.site("foot_sole").size = (1.1 * lander.foot_radius_m, 0.03, 0.0)
    spec.geom("pad").size = (pad.half_width_m, pad.half_width_m, 0.01)
    block = spec.geom("pad_block")
    block.size = (pad.half_width_m, pad.half_width_m, pad.thickness_m / 2.0)
    block.pos = (0.0, 0.0, -pad.thickness_m / 2.0)
    spec.joint("screw").range = screw.range_m
    spec.joint("qzs").range = (-params.qzs.stroke_m / 2.0, params.qzs.stroke_m / 2.0)


#: Elements a template must name (by kind, as MjSpec finds them).
_TEMPLATE_ELEMENTS = {
    "body": ("floating_support", "lander"),
    "geom": ("foot", "foot_plate", "pad", "pad_block"),
    "site": ("foot_sole", "imu"),
    "joint": ("screw", "qzs"),
    "tendon": ("balancer",),
    "actuator": ("servo", "guide_friction"),
    "sensor": ("grating_ruler", "encoder_pos", "encoder_vel", "lander_accel", "pad_force"),
    "key": ("home",),
}


#: Most bytes an MJCF template may hold (the packaged scene.xml and rig.xml: a few kB together).
MAX_TEMPLATE_BYTES = 2**22


def _load_template(xml_file: str | Path | None) -> mujoco.MjSpec:
    """The MJCF template (the packaged scene.xml by default), checked for every element the rig needs."""
    path = mjcf_dir() / "scene.xml" if xml_file is None else Path(xml_file)
    if not path.is_file() or path.stat().st_size > MAX_TEMPLATE_BYTES:  # not a FIFO, a device or gigabytes
        raise ValueError(
            f"xml_file {str(path)!r} is not an MJCF file (a regular file of at most {MAX_TEMPLATE_BYTES} bytes)"
        )
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as error:
        first = str(error).strip().splitlines()[0] if str(error).strip() else "unreadable"
        raise ValueError(f"xml_file {str(path)!r} is not a valid MJCF file: {first}") from None
    for kind, names in _TEMPLATE_ELEMENTS.items():
        missing = [name for name in names if getattr(spec, kind)(name) is None]
        if missing:
            raise ValueError(f"xml_file {str(path)!r} lacks the {kind} {', '.join(missing)} the rig needs")
    return spec


def _add_loads(spec: mujoco.MjSpec, loads_kg: tuple[float, ...]) -> None:
    for body in list(spec.body("lander").bodies):  # the template's weights, or an exported model's
        if body.name in TEMPLATE_LOADS or body.name.startswith("load_"):
            spec.delete(body)
    lander = spec.body("lander")
    deck_top = 0.77
    for i, mass in enumerate(loads_kg):
        radius, half_height = _load_geometry(mass)
        angle = 2.0 * math.pi * i / max(len(loads_kg), 1) + math.pi / 4.0
        body = lander.add_body(name=f"load_{i}", pos=(0.2 * math.cos(angle), 0.2 * math.sin(angle), deck_top))
        body.mass = mass
        body.ipos = (0.0, 0.0, half_height)
        inertia_xy = mass * (3.0 * radius**2 + (2.0 * half_height) ** 2) / 12.0
        body.inertia = (inertia_xy, inertia_xy, 0.5 * mass * radius**2)
        body.explicitinertial = True
        body.add_geom(
            name=f"load_{i}",
            default=spec.find_default("visual"),
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=(radius, half_height, 0.0),
            pos=(0.0, 0.0, half_height),
            material="weight",
        )


def _apply_flexible_unit(spec: mujoco.MjSpec, params: RigParams) -> None:
    """QZS spring (Eq. 17) on x, and the balancer's gas spring where ``placement`` puts it."""
    unit, qzs = flexible_unit(params), params.qzs
    joint = spec.joint("qzs")
    joint.stiffness = (qzs.residual_stiffness_n_per_m, 0.0, 0.0)
    joint.springref = unit.qzs_force_n / qzs.residual_stiffness_n_per_m
    joint.damping = (qzs.guide_damping_n_s_per_m, 0.0, 0.0)
    spec.actuator("guide_friction").set_to_dcmotor(
        motorconst=(0.0, 0.0),  # passive: no electrical branch, no inputs
        resistance=1.0,
        lugre=(
            qzs.guide_bristle_stiffness_n_per_m if qzs.guide_friction_n > 0 else 0.0,  # 0: no friction
            qzs.guide_bristle_damping_n_s_per_m,
            qzs.guide_friction_n,
            qzs.guide_static_friction_n,
            qzs.guide_stribeck_speed_m_s,
        ),
        ctrlspec=mujoco.mjtCtrlInput.mjINPUT_NONE,
    )
    if params.balancer.placement == "support_lander":  # the template's balancer acts on the screw
        spec.delete(spec.tendon("balancer"))
        spec.add_tendon(name="balancer").wrap_joint("qzs", 1.0)
    tendon = spec.tendon("balancer")
    tendon.stiffness = (unit.balancer_stiffness_n_per_m, 0.0, 0.0)
    free_length = unit.balancer_force_n / unit.balancer_stiffness_n_per_m
    tendon.springlength = (free_length, free_length)


def _apply_servo(spec: mujoco.MjSpec, params: RigParams, ideal_drive: bool, drive_scheme: str = "mujoco") -> None:
    """Screw stage and drive: gear, reflected inertia, friction, limits and the PI speed loop.

    The ideal drive (``ideal_drive``) is a speed source: a velocity actuator so stiff that the
    support follows the speed reference exactly, integrated implicitly so that it never chatters.
    Its torque is unlimited (a limited one would saturate on every change of the reference).
    """
    screw, servo = params.screw, params.servo
    spec.joint("screw").damping = (screw.viscous_n_s_per_m, 0.0, 0.0)
    actuator = spec.actuator("servo")
    actuator.gear = (screw.gear_rad_per_m, 0.0, 0.0, 0.0, 0.0, 0.0)
    actuator.armature = servo.rotor_inertia_kg_m2 + screw.screw_inertia_kg_m2
    if ideal_drive:
        kv = IDEAL_DRIVE_DAMPING_N_S_PER_M / screw.gear_rad_per_m**2
        actuator.set_to_velocity(kv=kv)
        return
    kp, kd = speed_loop_gains(params)
    actuator.set_to_dcmotor(
        motorconst=(servo.torque_constant_n_m_per_a, servo.torque_constant_n_m_per_a),
        resistance=servo.resistance_ohm,
        inductance=(0.0, servo.torque_filter_s),
        saturation=(servo.peak_torque_n_m if math.isfinite(servo.peak_torque_n_m) else 0.0, 0.0, 0.0),
        cogging=(servo.cogging_torque_n_m, float(servo.cogging_cycles_per_rev), servo.cogging_phase_rad),
        # The slew limiter interpolates the position reference (Rig.drive sets its rate).
        controller=(kp, 0.0, kd, servo_max_speed_rad_s(params), 0.0, servo.bus_voltage_v),
        lugre=(
            servo.bristle_stiffness_n_m_per_rad,
            servo.bristle_damping_n_m_s_per_rad,
            servo.coulomb_torque_n_m,
            servo.static_torque_n_m,
            servo.stribeck_speed_rad_s,
        ),
        ctrlspec=mujoco.mjtCtrlInput.mjINPUT_POS | mujoco.mjtCtrlInput.mjINPUT_VEL,
    )
    if drive_scheme == "midpoint":  # DRIVE_SCHEMES; the current at the step's start is set on the compiled model
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    if math.isfinite(screw.transmission_stiffness_n_per_m):
        _add_transmission(spec, params)


def _add_transmission(spec: mujoco.MjSpec, params: RigParams) -> None:
    """The belt and screw as one spring-damper (``ScrewStageParams.transmission_stiffness_n_per_m``)
    between the motor side and the support: the motor's angle becomes its own coordinate, the
    joint :data:`MOTOR_JOINT` (the angle over the gear, in metres of support travel), which the
    drive and the encoder act on and read; a fixed tendon, its length that joint's coordinate less
    the screw's, is the spring. Rotor, screw and pulleys (the actuator's armature) are on the
    motor side, the floating support on the other."""
    screw, servo = params.screw, params.servo
    motor_side_kg = (servo.rotor_inertia_kg_m2 + screw.screw_inertia_kg_m2) * screw.gear_rad_per_m**2
    reduced_kg = 1.0 / (1.0 / motor_side_kg + 1.0 / screw.support_mass_kg)
    stiffness = screw.transmission_stiffness_n_per_m
    # The joint's body carries no mass of its own (the armature is the motor side's inertia).
    body = spec.worldbody.add_body(name=MOTOR_JOINT, mass=_MOTOR_BODY_MASS_KG, inertia=[_MOTOR_BODY_MASS_KG] * 3)
    body.add_joint(name=MOTOR_JOINT, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=(0.0, 0.0, 1.0))
    tendon = spec.add_tendon(name="transmission")
    tendon.wrap_joint(MOTOR_JOINT, 1.0)
    tendon.wrap_joint("screw", -1.0)
    tendon.stiffness = (stiffness, 0.0, 0.0)
    tendon.damping = (2.0 * screw.transmission_damping_ratio * math.sqrt(stiffness * reduced_kg), 0.0, 0.0)
    tendon.springlength = (0.0, 0.0)
    spec.actuator("servo").target = MOTOR_JOINT
    for sensor in ("encoder_pos", "encoder_vel"):
        spec.sensor(sensor).objname = MOTOR_JOINT


def transmission_deflection_m(params: RigParams) -> float:
    """How far the motor side stands above the support at rest, m: the screw's static load on the
    transmission's spring (0 for a rigid transmission)."""
    stiffness = params.screw.transmission_stiffness_n_per_m
    return flexible_unit(params).screw_load_n / stiffness if math.isfinite(stiffness) else 0.0


def _count_pad_contacts(model: mujoco.MjModel, height_joint: str, thickness_m: float) -> int:
    """Contact points MuJoCo makes between foot and pad (a flat cylinder on a plane makes several)."""
    data = mujoco.MjData(model)
    foot, pad = model.geom("foot").id, model.geom("pad").id
    counts = []
    for depth in (1e-3, 0.5 * thickness_m, 0.999 * thickness_m):
        mujoco.mj_resetData(model, data)
        data.qpos[model.jnt_qposadr[model.joint(height_joint).id]] = -depth
        mujoco.mj_forward(model, data)
        counts.append(sum(1 for c in data.contact[: data.ncon] if {int(c.geom1), int(c.geom2)} == {foot, pad}))
    if len(set(counts)) != 1 or counts[0] < 1:
        raise RuntimeError(f"foot-pad contact count varies with depth ({counts}); pad stiffness would too")
    return counts[0]


def _apply_pad_contact(spec: mujoco.MjSpec, params: RigParams, mass_kg: float, height_joint: str) -> int:
    n_contacts = _count_pad_contacts(spec.compile(), height_joint, params.pad.thickness_m)
    pad = spec.geom("pad")
    pad.priority = 1  # the pad's contact parameters decide the foot-pad contact
    solref, solimp = pad_contact_solref(
        params.pad.stiffness_n_per_m, params.pad.damping_n_s_per_m, mass_kg, n_contacts, params.pad.impedance
    )
    pad.solref = solref
    pad.solimp = solimp
    return n_contacts


def check_physics_step(physics_step_s: float) -> float:
    """The physics step, validated against :data:`PHYSICS_STEP_RANGE_S`."""
    low, high = PHYSICS_STEP_RANGE_S
    step = validate.positive("physics_step_s", physics_step_s, "s")
    if not low <= step <= high:
        raise FieldError(f"physics_step_s must be in [{low:g}, {high:g}] s, got {physics_step_s!r}", "physics_step_s")
    return step


def build_spec(
    params: RigParams,
    loads_kg: tuple[float, ...] = (),
    xml_file: str | Path | None = None,
    physics_step_s: float = PHYSICS_STEP_S,
    ideal_drive: bool = False,
    drive_scheme: str = "mujoco",
) -> tuple[mujoco.MjSpec, int]:
    """The rig's MjSpec with every value of ``params`` applied, and its foot-pad contact count.

    ``xml_file`` replaces the packaged ``scene.xml`` template; it must name the same elements.
    ``drive_scheme`` is one of :data:`DRIVE_SCHEMES`.
    """
    validate.choice("drive_scheme", drive_scheme, DRIVE_SCHEMES)
    loads_kg = tuple(loads_kg)
    validate_loads(loads_kg, params.lander.mass_kg)
    physics_step_s = check_physics_step(physics_step_s)
    check_integrable(
        params, physics_step_s, ideal_drive, explicit_damping=drive_scheme == "midpoint" and not ideal_drive
    )
    spec = _load_template(xml_file)
    _apply_geometry_and_masses(spec, params, physics_step_s)
    _add_loads(spec, loads_kg)
    _apply_flexible_unit(spec, params)
    _apply_servo(spec, params, ideal_drive, drive_scheme)
    n_contacts = _apply_pad_contact(spec, params, params.lander.mass_kg + sum(loads_kg), "screw")
    home = spec.key("home")  # its coordinates, filled in by the contact count's compile
    motor_m = float(home.qpos[0]) + transmission_deflection_m(params)
    if spec.joint(MOTOR_JOINT) is not None:  # the motor's body is the world's last: its coordinate too
        home.qpos = (*list(home.qpos)[:-1], motor_m)
    home.ctrl = (0.0,) if ideal_drive else (motor_m * params.screw.gear_rad_per_m, 0.0)
    return spec, n_contacts


def export_spec(
    params: RigParams, loads_kg: tuple[float, ...] = (), physics_step_s: float = PHYSICS_STEP_S
) -> mujoco.MjSpec:
    """The rig as a self-contained model for use outside microg (``microg export-mjcf``).

    Its ``home`` keyframe is :meth:`Rig.reset`'s balanced rest at the template's height: positions,
    the drive's references and activation states (its interpolated reference and the torque
    filter's current), with the balancer trimmed there; loading it in ``mujoco.viewer`` holds still.
    The servo's control range spans the screw's stroke in motor radians, so that the viewer's
    sliders drive the support: its first input is the position reference, its second the speed
    reference (rad/s), both clamped to that range. Without the controller, x is unstable (Eq. 17's
    negative residual stiffness; the guide's static friction holds the balance within ~7 µm), so
    a slider step sends the lander to a guide stop. Test weights are in the model held off the
    lander, as at an episode's start (massless, drawn faint): give a weight's body its mass to place it.
    The pad's ``solref`` is the one for what the foot carries at home, the lander alone
    (:func:`pad_contact_solref`: it scales with the mass the contact sees).
    """
    spec, pad_contacts = build_spec(params, loads_kg, physics_step_s=physics_step_s)
    rig = Rig(spec.compile(), params, tuple(float(m) for m in loads_kg), pad_contacts, ideal_drive=False)
    data = mujoco.MjData(rig.model)
    home = spec.key("home")
    rig.reset(data, float(home.qpos[0]))  # the weights held off the lander, as at an episode's start
    spec.tendon("balancer").springlength = tuple(rig.model.tendon_lengthspring[rig._balancer])
    # the pad's solref for the mass it carries at home (the lander: the weights are held off)
    spec.geom("pad").solref = tuple(rig.model.geom_solref[rig.model.geom("pad").id])
    for i in range(len(loads_kg)):  # held: massless and drawn faint until a user gives a body its mass
        body, geom = spec.body(f"load_{i}"), spec.geom(f"load_{i}")
        body.mass, body.inertia = 0.0, (0.0, 0.0, 0.0)
        geom.rgba = tuple(rig.model.geom_rgba[rig.model.geom(f"load_{i}").id])
    home.qpos, home.ctrl, home.act = data.qpos.tolist(), data.ctrl.tolist(), data.act.tolist()
    servo = spec.actuator("servo")
    servo.ctrllimited = True
    servo.ctrlrange = tuple(np.array(spec.joint("screw").range) * rig.gear)
    return spec


def build_rig(
    params: RigParams | None = None,
    loads_kg: tuple[float, ...] = (),
    xml_file: str | Path | None = None,
    physics_step_s: float = PHYSICS_STEP_S,
    ideal_drive: bool = False,
    drive_scheme: str = "mujoco",
) -> Rig:
    """Compile the rig for ``params`` (default: the paper's rig) with test weights ``loads_kg``,
    its drive stepped as ``drive_scheme`` (:data:`DRIVE_SCHEMES`) says."""
    params = RigParams() if params is None else params
    spec, n_contacts = build_spec(params, loads_kg, xml_file, physics_step_s, ideal_drive, drive_scheme)
    model = spec.compile()
    midpoint = drive_scheme == "midpoint" and not ideal_drive
    if midpoint:  # MuJoCo's compiler refuses actearly off for a dcmotor; the compiled model takes it
        model.actuator_actearly[model.actuator("servo").id] = False
    return Rig(model, params, tuple(float(m) for m in loads_kg), n_contacts, ideal_drive, midpoint)


@dataclass(frozen=True)
class PadTest:
    """The lander alone on the pad, the rig removed: a point mass on a vertical slide.

    Used for the drop test (field 0, Section 2's free collision) and for the ideal-microgravity
    reference (field m_ext g / (M + m_ext)). The lander's height coordinate is the foot height.
    """

    model: mujoco.MjModel
    params: RigParams
    pad_contacts: int

    @property
    def mass_kg(self) -> float:
        return self.params.lander.mass_kg


def build_pad_test(
    params: RigParams | None = None, field_m_s2: float = 0.0, physics_step_s: float = PHYSICS_STEP_S
) -> PadTest:
    """The rig's lander and pad without support, QZS, balancer or servo, in a field of ``field_m_s2``.

    The floating support is fixed at touchdown, so the QZS joint becomes the lander's free height
    coordinate; spring, friction and guide limits are removed with the rest of the rig.
    """
    params = RigParams() if params is None else params
    validate.non_negative("field", field_m_s2, "m/s^2")
    spec = _load_template(None)
    _apply_geometry_and_masses(spec, params, physics_step_s)
    _add_loads(spec, ())
    spec.option.gravity = (0.0, 0.0, -field_m_s2)
    for sensor in ("encoder_pos", "encoder_vel"):
        spec.delete(spec.sensor(sensor))
    spec.delete(spec.actuator("servo"))
    spec.delete(spec.tendon("balancer"))
    spec.delete(spec.key("home"))
    spec.delete(spec.joint("screw"))
    spec.joint("qzs").limited = mujoco.mjtLimited.mjLIMITED_FALSE
    n_contacts = _apply_pad_contact(spec, params, params.lander.mass_kg, "qzs")
    return PadTest(model=spec.compile(), params=params, pad_contacts=n_contacts)
