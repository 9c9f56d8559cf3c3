"""Parameters -> MuJoCo model: the rig of ``mjcf/scene.xml`` with every force law from params.

:func:`build_rig` loads the MJCF template with :class:`mujoco.MjSpec`, writes every physical value
of :class:`~microg_env.params.RigParams` into it (masses, geometry, springs, friction, servo drive,
pad contact), adds the external loads of a run and compiles. :class:`Rig` holds the compiled model
and the addresses a simulation needs. :func:`pad_contact_solref` turns the pad's K and D into
MuJoCo's ``solref``/``solimp``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from microg_env.params import RigParams

#: Density of the steel test weights (for their size only; their mass is what matters).
_STEEL_DENSITY_KG_M3 = 7850.0
#: Template load bodies in rig.xml (the paper's weights, Table 2); build_rig replaces them.
TEMPLATE_LOADS = {"load_50g": 0.05, "load_490g": 0.49, "load_1kg": 1.0}
#: Depths at which the number of foot-pad contact points is counted (it must not change).
_PROBE_DEPTHS_M = (1e-3, 2e-2)


def mjcf_dir() -> Path:
    """Folder holding scene.xml: inside the installed package, or the repository's ``mjcf/``."""
    package = Path(__file__).resolve().parents[1]
    for candidate in (package / "mjcf", package.parent / "mjcf"):
        if (candidate / "scene.xml").is_file():
            return candidate
    raise FileNotFoundError(f"scene.xml not found next to {package}; the package is incomplete")


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
    every other force during contact is scaled by ~1 - n d (0.9996 for d = 1e-4, n = 4), so the
    static sink under a load F is F/K to 4e-4.
    """
    for name, value in (
        ("stiffness", stiffness_n_per_m),
        ("damping", damping_n_s_per_m),
        ("mass", mass_kg),
    ):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    if n_contacts < 1:
        raise ValueError(f"n_contacts must be >= 1, got {n_contacts!r}")
    scale = (1.0 + (n_contacts - 1) * impedance) / (n_contacts * mass_kg)
    solref = np.array([-stiffness_n_per_m * scale, -damping_n_s_per_m * scale])
    solimp = np.array([impedance, impedance, 0.001, 0.5, 2.0])
    return solref, solimp


class Rig:
    """A compiled rig model, the addresses a simulation needs, and which test weights are placed.

    A test weight that is not yet placed is held off the lander (by the experimenter's hand): it
    has no mass in the model, so it neither weighs on the lander nor adds to its inertia. Placing
    it (:meth:`place_loads`) gives it its mass and retunes the pad contact to the new total mass.
    The load configuration lives in ``model``, so use one Rig per simulated rig.
    """

    def __init__(self, model: mujoco.MjModel, params: RigParams, loads_kg: tuple[float, ...], pad_contacts: int):
        self.model = model
        self.params = params
        self.loads_kg = loads_kg
        self.pad_contacts = pad_contacts
        screw, qzs = model.joint("screw").id, model.joint("qzs").id
        self.screw_qpos = int(model.jnt_qposadr[screw])
        self.qzs_qpos = int(model.jnt_qposadr[qzs])
        self.screw_dof = int(model.jnt_dofadr[screw])
        self.qzs_dof = int(model.jnt_dofadr[qzs])
        self.gear = params.screw.gear_rad_per_m  # motor radians per metre of support travel
        self.load_bodies = np.array([model.body(f"load_{i}").id for i in range(len(loads_kg))], dtype=int)
        self._load_geoms = np.array([model.geom(f"load_{i}").id for i in range(len(loads_kg))], dtype=int)
        self._load_inertia = model.body_inertia[self.load_bodies].copy()
        self._pad_geom = model.geom("pad").id
        self.placed = np.ones(len(loads_kg), dtype=bool)  # as compiled: every weight on the lander
        self.placed_load_kg = float(sum(loads_kg))  # total of the weights on the lander, kg

    def place_loads(self, placed: np.ndarray | list[bool]) -> None:
        """Put each test weight on the lander (True) or hold it off (False)."""
        placed = np.asarray(placed, dtype=bool)
        if placed.shape != self.placed.shape:
            raise ValueError(f"placed must have one entry per load ({self.placed.size}), got shape {placed.shape}")
        self.placed[:] = placed
        self.placed_load_kg = float(np.dot(self.loads_kg, placed)) if self.loads_kg else 0.0
        model = self.model
        model.body_mass[self.load_bodies] = np.where(placed, self.loads_kg, 0.0)
        model.body_inertia[self.load_bodies] = np.where(placed[:, None], self._load_inertia, 0.0)
        model.geom_rgba[self._load_geoms, 3] = np.where(placed, 1.0, 0.25)  # held weights drawn faint
        pad = self.params.pad
        solref, _ = pad_contact_solref(
            pad.stiffness_n_per_m,
            pad.damping_n_s_per_m,
            self.params.lander.mass_kg + self.placed_load_kg,
            self.pad_contacts,
            pad.impedance,
        )
        model.geom_solref[self._pad_geom] = solref

    def foot_height(self, data: mujoco.MjData) -> float:
        """Height of the foot's sole above the undeformed pad, m (negative: deforming the pad)."""
        return float(data.qpos[self.screw_qpos] + data.qpos[self.qzs_qpos])

    def lander_velocity(self, data: mujoco.MjData) -> float:
        """Vertical velocity of the lander, m/s (up positive)."""
        return float(data.qvel[self.screw_dof] + data.qvel[self.qzs_dof])

    def reset(self, data: mujoco.MjData, height_m: float) -> None:
        """Balanced rest: foot ``height_m`` above the pad, x = 0, servo holding, no weight placed."""
        self.place_loads(np.zeros(len(self.loads_kg), dtype=bool))
        mujoco.mj_resetData(self.model, data)
        data.qpos[self.screw_qpos] = height_m
        # The speed loop's position term holds the weight with a small lag behind its reference.
        data.ctrl[:] = ((height_m + self.holding_sag_m()) * self.gear, 0.0)
        mujoco.mj_forward(self.model, data)

    def holding_sag_m(self) -> float:
        """Support lag at which the speed loop's position term carries lander and support, m."""
        weight = (self.params.lander.mass_kg + self.params.screw.support_mass_kg) * self.params.gravity_m_s2
        kp, _ = speed_loop_gains(self.params)
        return weight / (self.gear**2 * kp)


def _load_geometry(mass_kg: float) -> tuple[float, float]:
    """Radius and half-height of a steel cylinder of height 1.5 x radius with this mass."""
    radius = (mass_kg / (_STEEL_DENSITY_KG_M3 * math.pi * 1.5)) ** (1.0 / 3.0)
    return radius, 0.75 * radius


def _validate_loads(loads_kg: tuple[float, ...], lander_mass_kg: float) -> None:
    """Test weights are small excitations of the balanced lander.

    The rig simulates 1e-2 to 1e-4 g (Conclusions); a total m above M/99 would make the simulated
    field m g / (M + m) exceed 1e-2 g.
    """
    for i, mass in enumerate(loads_kg):
        if not (isinstance(mass, int | float) and math.isfinite(mass) and mass > 0):
            raise ValueError(f"load {i} mass must be a positive finite number of kg, got {mass!r}")
    limit = lander_mass_kg / 99.0
    if sum(loads_kg) > limit:
        raise ValueError(
            f"loads totalling {sum(loads_kg):g} kg on a {lander_mass_kg:g} kg lander exceed {limit:.2f} kg, "
            f"the most that keeps the simulated field within the rig's 1e-2 g range"
        )


def _apply_geometry_and_masses(spec: mujoco.MjSpec, params: RigParams) -> None:
    lander, pad, screw = params.lander, params.pad, params.screw
    spec.option.timestep = params.timestep_s
    spec.option.gravity = (0.0, 0.0, -params.gravity_m_s2)
    spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_DIAGEXACT
    spec.body("lander").mass = lander.mass_kg
    spec.body("floating_support").mass = screw.support_mass_kg
    foot = spec.geom("foot")
    foot.size = (lander.foot_radius_m, lander.foot_height_m / 2.0, 0.0)
    foot.pos = (0.0, 0.0, lander.foot_height_m / 2.0)
    spec.site("foot_sole").size = (1.1 * lander.foot_radius_m, 0.03, 0.0)
    pad_geom = spec.geom("pad")
    pad_geom.size = (pad.half_width_m, pad.half_width_m, pad.thickness_m / 2.0)
    pad_geom.pos = (0.0, 0.0, -pad.thickness_m / 2.0)
    spec.joint("screw").range = screw.range_m
    spec.joint("qzs").range = (-params.qzs.stroke_m / 2.0, params.qzs.stroke_m / 2.0)


def _add_loads(spec: mujoco.MjSpec, loads_kg: tuple[float, ...]) -> None:
    for name in TEMPLATE_LOADS:
        spec.delete(spec.body(name))
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


@dataclass(frozen=True)
class FlexibleUnit:
    """QZS mechanism and nitrogen balancer, balanced to carry the lander at x = 0."""

    qzs_force_n: float  # QZS force at x = 0: its weight share plus Eq. (17)'s constant term
    balancer_force_n: float  # the rest of the lander's weight (the balancer is trimmed, Section 4.1)
    balancer_stiffness_n_per_m: float
    stiffness_n_per_m: float  # QZS (Eq. 17) plus balancer: the force lost per metre of x


def flexible_unit(params: RigParams) -> FlexibleUnit:
    """Forces and stiffness of the flexible unit for ``params``."""
    qzs, weight = params.qzs, params.lander.mass_kg * params.gravity_m_s2
    qzs_force = qzs.weight_share * weight + qzs.force_offset_n
    balancer_force = weight - qzs_force
    if balancer_force <= 0:
        raise ValueError(f"QZSParams.weight_share {qzs.weight_share!r} leaves the balancer no weight to carry")
    balancer_stiffness = params.balancer.stiffness_n_per_m(balancer_force)
    return FlexibleUnit(qzs_force, balancer_force, balancer_stiffness, qzs.stiffness_n_per_m + balancer_stiffness)


def _apply_flexible_unit(spec: mujoco.MjSpec, params: RigParams) -> None:
    """QZS spring (Eq. 17) and nitrogen balancer as preloaded linear springs on x."""
    unit, qzs = flexible_unit(params), params.qzs
    joint = spec.joint("qzs")
    joint.stiffness = (qzs.stiffness_n_per_m, 0.0, 0.0)
    joint.springref = unit.qzs_force_n / qzs.stiffness_n_per_m
    joint.damping = (qzs.guide_damping_n_s_per_m, 0.0, 0.0)
    joint.frictionloss = qzs.guide_friction_n
    tendon = spec.tendon("balancer")
    free_length = unit.balancer_force_n / unit.balancer_stiffness_n_per_m
    tendon.stiffness = (unit.balancer_stiffness_n_per_m, 0.0, 0.0)
    tendon.springlength = (free_length, free_length)


def speed_loop_gains(params: RigParams) -> tuple[float, float]:
    """The drive's PI speed loop as dcmotor gains (kp, kd), N m/rad and N m s/rad.

    kd = Kv J and kp = Kv J / Ti, with J the inertia the loop drives at the motor: rotor, screw
    and the floating support reflected through the screw (the lander hangs on the 1.2 Hz QZS
    spring, far below the loop's bandwidth, so the loop does not feel it).
    """
    screw, servo = params.screw, params.servo
    loop_inertia = (
        servo.rotor_inertia_kg_m2 + screw.screw_inertia_kg_m2 + screw.support_mass_kg / screw.gear_rad_per_m**2
    )
    kd = 2.0 * math.pi * servo.speed_loop_gain_hz * loop_inertia
    return kd / servo.speed_integral_time_s, kd


def _apply_servo(spec: mujoco.MjSpec, params: RigParams) -> None:
    """Screw stage and drive: gear, reflected inertia, friction, limits and the PI speed loop."""
    screw, servo = params.screw, params.servo
    kp, kd = speed_loop_gains(params)
    spec.joint("screw").damping = (screw.viscous_n_s_per_m, 0.0, 0.0)
    actuator = spec.actuator("servo")
    actuator.gear = (screw.gear_rad_per_m, 0.0, 0.0, 0.0, 0.0, 0.0)
    actuator.armature = servo.rotor_inertia_kg_m2 + screw.screw_inertia_kg_m2
    actuator.set_to_dcmotor(
        motorconst=(servo.torque_constant_n_m_per_a, servo.torque_constant_n_m_per_a),
        resistance=servo.resistance_ohm,
        saturation=(servo.peak_torque_n_m if math.isfinite(servo.peak_torque_n_m) else 0.0, 0.0, 0.0),
        cogging=(servo.cogging_torque_n_m, float(servo.cogging_cycles_per_rev), 0.0),
        controller=(kp, 0.0, kd, 0.0, 0.0, servo.bus_voltage_v),
        lugre=(
            servo.bristle_stiffness_n_m_per_rad,
            servo.bristle_damping_n_m_s_per_rad,
            servo.coulomb_torque_n_m,
            servo.static_torque_n_m,
            servo.stribeck_speed_rad_s,
        ),
        ctrlspec=mujoco.mjtCtrlInput.mjINPUT_POS | mujoco.mjtCtrlInput.mjINPUT_VEL,
    )


def _count_pad_contacts(model: mujoco.MjModel, height_joint: str) -> int:
    """Contact points MuJoCo makes between foot and pad (a flat cylinder on a box makes several)."""
    data = mujoco.MjData(model)
    foot, pad = model.geom("foot").id, model.geom("pad").id
    counts = []
    for depth in _PROBE_DEPTHS_M:
        mujoco.mj_resetData(model, data)
        data.qpos[model.jnt_qposadr[model.joint(height_joint).id]] = -depth
        mujoco.mj_forward(model, data)
        counts.append(sum(1 for c in data.contact[: data.ncon] if {int(c.geom1), int(c.geom2)} == {foot, pad}))
    if len(set(counts)) != 1 or counts[0] < 1:
        raise RuntimeError(f"foot-pad contact count varies with depth ({counts}); pad stiffness would too")
    return counts[0]


def _apply_pad_contact(spec: mujoco.MjSpec, params: RigParams, mass_kg: float, height_joint: str) -> int:
    n_contacts = _count_pad_contacts(spec.compile(), height_joint)
    pad = spec.geom("pad")
    pad.priority = 1  # the pad's contact parameters decide the foot-pad contact
    solref, solimp = pad_contact_solref(
        params.pad.stiffness_n_per_m, params.pad.damping_n_s_per_m, mass_kg, n_contacts, params.pad.impedance
    )
    pad.solref = solref
    pad.solimp = solimp
    return n_contacts


def build_spec(
    params: RigParams, loads_kg: tuple[float, ...] = (), xml_file: str | Path | None = None
) -> tuple[mujoco.MjSpec, int]:
    """The rig's MjSpec with every value of ``params`` applied, and its foot-pad contact count.

    ``xml_file`` replaces the packaged ``scene.xml`` template; it must name the same elements.
    """
    loads_kg = tuple(loads_kg)
    _validate_loads(loads_kg, params.lander.mass_kg)
    spec = mujoco.MjSpec.from_file(str(mjcf_dir() / "scene.xml" if xml_file is None else xml_file))
    _apply_geometry_and_masses(spec, params)
    _add_loads(spec, loads_kg)
    _apply_flexible_unit(spec, params)
    _apply_servo(spec, params)
    n_contacts = _apply_pad_contact(spec, params, params.lander.mass_kg + sum(loads_kg), "screw")
    home = spec.key("home")
    home.ctrl = (float(home.qpos[0]) * params.screw.gear_rad_per_m, 0.0)
    return spec, n_contacts


def build_rig(
    params: RigParams | None = None, loads_kg: tuple[float, ...] = (), xml_file: str | Path | None = None
) -> Rig:
    """Compile the rig for ``params`` (default: the paper's rig) with test weights ``loads_kg``."""
    params = RigParams() if params is None else params
    spec, n_contacts = build_spec(params, loads_kg, xml_file)
    return Rig(spec.compile(), params, tuple(float(m) for m in loads_kg), n_contacts)


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


def build_pad_test(params: RigParams | None = None, field_m_s2: float = 0.0) -> PadTest:
    """The rig's lander and pad without support, QZS, balancer or servo, in a field of ``field_m_s2``.

    The floating support is fixed at touchdown, so the QZS joint becomes the lander's free height
    coordinate; spring, friction and guide limits are removed with the rest of the rig.
    """
    params = RigParams() if params is None else params
    if not (math.isfinite(field_m_s2) and field_m_s2 >= 0):
        raise ValueError(f"field must be a finite acceleration >= 0 m/s^2, got {field_m_s2!r}")
    spec = mujoco.MjSpec.from_file(str(mjcf_dir() / "scene.xml"))
    _apply_geometry_and_masses(spec, params)
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
