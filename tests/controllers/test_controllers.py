"""The baselines: the PID law and its 1e-4 g level, the feed-forward, its adaptive variant and its
dither, the oracle."""

from dataclasses import replace

import numpy as np
import pytest

from microg_env.controllers import BASELINES, PID, PIDGains, PolicyController, load_gains, make_controller
from microg_env.controllers.base import tell_plants
from microg_env.controllers.feedforward import (
    DRIVE_TORQUE_FIELDS,
    PLANT_FIELDS,
    DitheredAdaptiveFeedforward,
    DitherSettings,
    adapt_friction,
    plant_model,
)
from microg_env.envs.landing import MicroGravityLandingEnv
from microg_env.imperfections import DomainRandomization
from microg_env.interface import OBSERVATION_INDEX, OBSERVATION_SCALES, SCALES
from microg_env.params import RigParams
from microg_env.rollout.episode import run_episode, run_with_metrics
from microg_env.rollout.runner import run_all
from microg_env.rollout.spec import RunSpec
from microg_env.scenarios import comparison_scenarios

GAINS = PIDGains(kp_per_s=100.0, ki_per_s2=5000.0, kd=2.0, derivative_filter_s=0.0, integral_limit_m_s=0.5)
PERIOD = 1e-3
#: Condition 1 to past its first contact (touchdown at 4.8 s, lift-off at 6.0 s): its collision metrics are
#: those of the whole 30 s run, bit for bit.
COLLIDED_S = 9.0


def _observation(x=0.0, x_rate=0.0, support_velocity=0.0) -> np.ndarray:
    obs = np.zeros(len(OBSERVATION_SCALES), dtype=np.float32)
    obs[OBSERVATION_INDEX["x"]] = x / OBSERVATION_SCALES["x"]
    obs[OBSERVATION_INDEX["x_rate"]] = x_rate / OBSERVATION_SCALES["x_rate"]
    obs[OBSERVATION_INDEX["support_velocity"]] = support_velocity / OBSERVATION_SCALES["support_velocity"]
    return obs


def test_pid_law():
    pid = PID(GAINS, PERIOD)
    action = pid(_observation(x=1e-4, x_rate=2e-4), {})
    expected = 100.0 * 1e-4 + 5000.0 * 1e-4 * PERIOD + 2.0 * 2e-4
    assert action.shape == (1,)
    assert action.dtype == np.float32
    assert float(action[0]) * 1.25 == pytest.approx(expected, rel=1e-6)
    second = pid(_observation(x=1e-4, x_rate=2e-4), {})  # the integral keeps adding
    assert float(second[0]) * 1.25 == pytest.approx(expected + 5000.0 * 1e-4 * PERIOD, rel=1e-6)
    pid.reset()
    assert float(pid(_observation(), {})[0]) == 0.0


def test_derivative_on_measurement_ignores_the_lander_and_uses_the_support():
    classic, dom = PID(GAINS, PERIOD), PID(GAINS, PERIOD, derivative_on_measurement=True)
    # A jump of the lander's velocity shows in dx/dt only: the classic D reacts, DoM does not.
    assert float(classic(_observation(x_rate=0.01), {})[0]) != 0.0
    assert float(dom(_observation(x_rate=0.01), {})[0]) == 0.0
    # DoM damps the support's own motion: D = -Kd dz_support/dt.
    dom.reset()
    assert float(dom(_observation(support_velocity=0.01), {})[0]) * 1.25 == pytest.approx(-2.0 * 0.01, rel=1e-6)


def test_output_is_clipped_and_the_integral_does_not_wind_up():
    gains = PIDGains(kp_per_s=100.0, ki_per_s2=5000.0, kd=0.0, derivative_filter_s=0.0, integral_limit_m_s=1.25)
    pid = PID(gains, PERIOD)
    for _ in range(1000):  # x = 5 mm for a second: P gives 0.5 m/s, the integral the rest up to 1.25
        action = pid(_observation(x=0.005), {})
    assert float(action[0]) == 1.0
    # Conditional integration stops the integral within one step's increment (0.025 m/s) below
    # where the command saturates (1.25 - 0.5 m/s), instead of at its 1.25 m/s clamp.
    assert 0.725 - 1e-9 <= pid._integral <= 0.75 + 1e-9


def test_gains_come_from_the_config_file():
    for name in ("pid", "pid-dom"):
        gains = load_gains(name)
        assert gains.kp_per_s > 0
        assert gains.ki_per_s2 > 0
    assert make_controller("pid-dom", PERIOD).derivative_on_measurement
    with pytest.raises(ValueError, match="controller"):
        make_controller("lqr", PERIOD)
    with pytest.raises(ValueError, match="kp_per_s"):
        PIDGains(kp_per_s=-1.0, ki_per_s2=1.0, kd=0.0, derivative_filter_s=0.0, integral_limit_m_s=1.0)


def test_policy_controller_wraps_predict():
    class Constant:
        def predict(self, observation, deterministic=True):
            return np.array([0.25]), None

    controller = PolicyController(Constant())
    controller.reset()
    assert controller(_observation(), {}).tolist() == [0.25]


@pytest.fixture(scope="module")
def pid_runs():
    """The tuned PID on the paper's three conditions, every imperfection on (30 s each)."""
    runs = {}
    for number in (1, 2, 3):
        env = MicroGravityLandingEnv(condition=number)
        runs[number] = run_with_metrics(env, make_controller("pid", env.settings.control_period_s), seed=0)[2]
    return runs


@pytest.mark.slow
def test_pid_reaches_the_1e_4_g_level_in_condition_3(pid_runs):
    metrics = pid_runs[3]
    assert metrics.termination_reason is None
    level = metrics.microgravity_level_g[0]  # the 50 g stage
    assert 0.5e-4 <= level <= 1.5e-4
    assert abs(metrics.compensation_error_pct[0]) <= 5.0
    assert abs(metrics.compensation_error_pct[1]) <= 5.0


@pytest.mark.parametrize("number", [1, 2])
@pytest.mark.slow
def test_pid_conditions_1_and_2_within_2_percent(pid_runs, number):
    metrics = pid_runs[number]
    assert metrics.termination_reason is None
    assert abs(metrics.compensation_error_pct[0]) <= 2.0


@pytest.mark.parametrize("number", [1, 2, 3])
@pytest.mark.slow
def test_pid_peak_deformation_within_3_percent_of_ideal_microgravity(pid_runs, number):
    metrics = pid_runs[number]
    assert metrics.max_deformation_m == pytest.approx(metrics.reference_max_deformation_m, rel=0.03)


@pytest.mark.slow
def test_pid_dom_meets_the_same_targets():
    env = MicroGravityLandingEnv(condition=3)
    metrics = run_with_metrics(env, make_controller("pid-dom", env.settings.control_period_s), seed=1)[2]
    assert metrics.termination_reason is None
    assert 0.5e-4 <= metrics.microgravity_level_g[0] <= 1.5e-4
    assert metrics.max_deformation_m == pytest.approx(metrics.reference_max_deformation_m, rel=0.03)


class _Sealed(dict):
    """An info dictionary a controller may pass on but never read."""

    def __getitem__(self, key):
        raise AssertionError(f"the controller read info[{key!r}]: the simulator's truth")

    get = __getitem__


@pytest.mark.parametrize("name", BASELINES)
def test_baselines_read_only_the_observation(name):
    env = MicroGravityLandingEnv(condition=2)
    controller = make_controller(name, env.settings.control_period_s)
    observation, _ = env.reset(seed=0)
    controller.reset()
    tell_plants(controller, np.zeros(1, dtype=np.int64), [env.params], ideal_drive=False)  # the oracle's one extra
    for _ in range(200):
        observation, *_ = env.step(controller(observation, _Sealed()))


def test_feedforward_follows_a_setpoint_and_resets():
    env = MicroGravityLandingEnv(condition=2)
    controller = make_controller("feedforward", env.settings.control_period_s)
    observation, info = env.reset(seed=0)
    controller.reset()
    controller.setpoint_m[0] = 1e-6  # rig 0's setpoint (a controller holds one per rig)
    xs = []
    for _ in range(1500):
        observation, _, _, _, info = env.step(controller(observation, info))
        xs.append(info["x_m"])
    assert np.mean(xs[500:]) == pytest.approx(1e-6, abs=0.1e-6)
    first = controller(observation, info)
    controller.reset()
    assert controller.setpoint_m[0] == 0.0  # a new episode holds x at 0 again
    assert controller(observation, info) != first  # and its estimator restarts from this observation


@pytest.mark.slow
def test_the_oracle_is_the_feedforward_on_the_nominal_plant_and_far_better_on_a_drawn_one():
    """Told the nominal plant, the oracle acts as the feed-forward bit for bit; on drawn plants and
    drives (seeds 1000-1001 of condition 1, its first 9 s: past the collision) it uses what it is
    told and lands with at least 3 times less x at the collision (measured: 15 and 5 times)."""
    nominal = MicroGravityLandingEnv(condition=1)
    runs = {
        n: run_episode(nominal, make_controller(n, PERIOD), seed=3, duration_s=2.0) for n in ("feedforward", "oracle")
    }
    np.testing.assert_array_equal(runs["oracle"].command_m_s, runs["feedforward"].command_m_s)
    drawn = MicroGravityLandingEnv(condition=1, domain_randomization=DomainRandomization.full())
    for seed in (1000, 1001):
        metrics = {
            n: run_with_metrics(drawn, make_controller(n, PERIOD), seed, COLLIDED_S)[2]
            for n in ("feedforward", "oracle")
        }
        excursion = {n: each.flexible_unit_excursion_collision_m for n, each in metrics.items()}
        assert excursion["oracle"] * 3 < excursion["feedforward"], (seed, excursion)


def _pad_row(height_m: float, rate_m_s: float, pad_force_n: float) -> np.ndarray:
    """An observation of the foot ``height_m`` above touchdown, moving at ``rate_m_s`` (the support's
    speed; x still), with the pad force sensor reading ``pad_force_n``."""
    obs = _observation(support_velocity=rate_m_s)
    obs[OBSERVATION_INDEX["height"]] = height_m / OBSERVATION_SCALES["height"]
    obs[OBSERVATION_INDEX["support_position"]] = (0.01 + height_m) / OBSERVATION_SCALES["support_position"]
    obs[OBSERVATION_INDEX["pad_force"]] = pad_force_n / OBSERVATION_SCALES["pad_force"]
    return obs


def _first_action(name: str, observation: np.ndarray) -> float:
    controller = make_controller(name, 2e-3)
    controller.reset()
    return float(controller(observation)[0])


def test_the_pad_model_gives_eq_1s_force_where_the_rig_reads_none():
    """``adaptive-friction`` where the pad force reads exactly 0 acts at first as ``adaptive-dither`` shown
    Eq. (1)'s K d + D d' (Table 1's K, D) at the measured depth and rate; shown a reading, it acts as
    the dither; above the pad, or leaving it faster than the spring pushes, the force is 0."""
    pad = RigParams().pad
    depth, rate = 2e-3, -10e-3  # 2 mm into the pad, the foot still sinking at 10 mm/s
    force = pad.stiffness_n_per_m * depth - pad.damping_n_s_per_m * rate
    modelled = _first_action("adaptive-friction", _pad_row(-depth, rate, 0.0))
    assert modelled == pytest.approx(_first_action("adaptive-dither", _pad_row(-depth, rate, force)), rel=1e-6)
    assert modelled != _first_action("adaptive-dither", _pad_row(-depth, rate, 0.0))
    read = _pad_row(-depth, rate, 3.0)
    assert _first_action("adaptive-friction", read) == _first_action("adaptive-dither", read)
    for height, speed in ((1e-3, -10e-3), (-1e-4, 0.5)):  # above the pad; a 0.1 mm contact left at 0.5 m/s
        row = _pad_row(height, speed, 0.0)
        assert _first_action("adaptive-friction", row) == _first_action("adaptive-dither", row)


def test_the_friction_level_moves_by_the_torque_the_speed_loops_lag_shows():
    """The level's factor moves by gain x kp x slow lag over the nominal level at the measured speed,
    in the direction of motion; not below the lowest speed; never out of FRICTION_FACTOR_RANGE."""
    controller = make_controller("adaptive-friction", 1e-3)
    controller.reset()
    nominal, (gain, min_speed, lowest, highest) = controller.nominal, controller.friction_constants
    gear, kp = nominal[PLANT_FIELDS.index("gear")], nominal[PLANT_FIELDS.index("kp_speed")]
    coulomb, static = nominal[PLANT_FIELDS.index("coulomb")], nominal[PLANT_FIELDS.index("static")]
    speed = -4.0  # rad/s, descending: far above the Stribeck speed, so the level is Coulomb's
    row = _observation(support_velocity=speed / gear)[None]
    controller._slow[0] = -2e-5  # lagging behind a descending reference: more friction than modelled
    adapt_friction(row, np.zeros(1, dtype=np.int64), SCALES, controller._plant, nominal, controller._slow,
                   *controller.friction_constants)  # fmt: skip
    factor = 1.0 + gain * kp * 2e-5 / coulomb
    assert controller._plant[0, PLANT_FIELDS.index("coulomb")] == pytest.approx(factor * coulomb, rel=1e-3)
    assert controller._plant[0, PLANT_FIELDS.index("static")] == pytest.approx(factor * static, rel=1e-3)
    slow = _observation(support_velocity=0.5 * min_speed / gear)[None]
    before = controller._plant.copy()
    adapt_friction(slow, np.zeros(1, dtype=np.int64), SCALES, controller._plant, nominal, controller._slow,
                   *controller.friction_constants)  # fmt: skip
    np.testing.assert_array_equal(controller._plant, before)
    controller._slow[0] = 1.0  # a torque error no friction explains
    adapt_friction(row, np.zeros(1, dtype=np.int64), SCALES, controller._plant, nominal, controller._slow,
                   *controller.friction_constants)  # fmt: skip
    assert controller._plant[0, PLANT_FIELDS.index("coulomb")] == pytest.approx(lowest * coulomb)
    assert highest > 1.75  # above the widest drawn plant's factor (DomainRandomization.wider)


@pytest.mark.slow
def test_adaptive_friction_learns_a_friction_level_it_was_not_told():
    """On plants drawn with the friction 1.51 and 0.50 times nominal (held-out schedule
    ``heavy-second``, seeds 4000 and 4001, ranges wider than training's) the learned factor ends
    on the drawn one's side of 1 (measured 1.76 and 0.49), and x at the collision is at most 0.7
    times ``adaptive-dither``'s (measured 0.41 and 0.20)."""
    env = MicroGravityLandingEnv(
        scenario=comparison_scenarios()["heavy-second"], domain_randomization=DomainRandomization.wider()
    )
    for seed, side in ((4000, 1.0), (4001, -1.0)):
        runs = {}
        for name in ("adaptive-dither", "adaptive-friction"):
            controller = make_controller(name, env.settings.control_period_s)
            runs[name] = run_with_metrics(env, controller, seed)[2].flexible_unit_excursion_collision_m
        drawn = env.params.servo.coulomb_torque_n_m / RigParams().servo.coulomb_torque_n_m
        learned = (
            controller._plant[0, PLANT_FIELDS.index("coulomb")] / controller.nominal[PLANT_FIELDS.index("coulomb")]
        )
        assert side * (drawn - 1.0) > 0.4
        assert side * (learned - 1.0) > 0.2, (seed, learned, drawn)
        assert runs["adaptive-friction"] < 0.7 * runs["adaptive-dither"], (seed, runs)


def test_the_oracle_reads_the_true_pad_where_the_rig_has_no_force_sensor():
    """On the paper's sensors the oracle takes the pad force from the episode's true pad: its x at the
    collision is within 5 % of its own with the pad force sensor (it was 3 times that without)."""
    specs = [
        RunSpec("condition-1", "oracle", seed, randomize="wider", sensor_set=sensors, duration_s=COLLIDED_S)
        for seed in (1000, 1001)
        for sensors in ("extended", "paper")
    ]
    runs = [result.metrics.flexible_unit_excursion_collision_m for result in run_all(specs)]
    for extended, paper in zip(runs[::2], runs[1::2], strict=True):
        assert paper == pytest.approx(extended, rel=0.05)


def test_an_oracle_told_an_ideal_drive_asks_it_for_no_torque():
    params = RigParams()
    drive, ideal = plant_model(params), plant_model(params, ideal_drive=True)
    torque = [PLANT_FIELDS.index(name) for name in DRIVE_TORQUE_FIELDS]
    assert (ideal[torque] == 0).all()
    assert (drive[torque] != 0).all()
    np.testing.assert_array_equal(np.delete(ideal, torque), np.delete(drive, torque))


def test_the_oracle_refuses_to_act_on_a_plant_it_was_not_told():
    env = MicroGravityLandingEnv(condition=1)
    oracle = make_controller("oracle", PERIOD)
    observation, _ = env.reset(seed=0)
    oracle.reset()
    with pytest.raises(RuntimeError, match="oracle: rig 0's plant was not given"):
        oracle(observation)


@pytest.mark.slow
def test_the_adaptive_feedforward_learns_a_cogging_it_was_not_told():
    """A motor whose cogging is 0.3 N m at phase 2 rad (the nominal model: 0.24 N m at 0): the
    adaptive feed-forward ends condition 1's first 9 s (past the collision) with an estimate within
    10 % and 0.15 rad (measured: 0.311 N m, 2.08 rad; 0.307 N m, 2.06 rad after 30 s) and five times
    less x in free fall than the feed-forward (measured: ten).
    On the nominal motor it keeps a third of the feed-forward's x in free fall (measured 0.069
    against 0.353 um) and at most 1.5 times its x at the collision (measured 1.30 times: 0.475
    against 0.366 um; 0.93 times under ``drive_scheme="mujoco"``, whose step error hid it)."""
    base = RigParams()
    other = replace(base, servo=replace(base.servo, cogging_phase_rad=2.0, cogging_torque_n_m=0.3))
    for params, check in ((other, "learns"), (base, "nominal")):
        env = MicroGravityLandingEnv(condition=1, params=params)
        adaptive = make_controller("adaptive", PERIOD)
        ours = run_with_metrics(env, adaptive, 3, COLLIDED_S)[2]
        theirs = run_with_metrics(env, make_controller("feedforward", PERIOD), 3, COLLIDED_S)[2]
        if check == "learns":
            assert adaptive._plant[0, 9] == pytest.approx(0.3, rel=0.1)
            assert adaptive._plant[0, 11] == pytest.approx(2.0, abs=0.15)
            assert ours.flexible_unit_excursion_free_fall_m * 5 < theirs.flexible_unit_excursion_free_fall_m
        else:
            assert ours.flexible_unit_excursion_free_fall_m * 3 < theirs.flexible_unit_excursion_free_fall_m
            assert ours.flexible_unit_excursion_collision_m <= theirs.flexible_unit_excursion_collision_m * 1.5
    adaptive.reset()
    np.testing.assert_array_equal(adaptive._plant[0], adaptive.nominal)  # a new episode starts from the nominal motor


def test_the_dither_is_a_square_wave_on_the_setpoint_a_residual_holds():
    """Each period the dithered controller acts as ``adaptive`` does with its setpoint moved by
    +A for half the dither's period, then -A (here A = 50 nm, 4 ms: two periods each), bit for bit,
    and the setpoint a residual wrote is still there after every call; a reset starts at +A again
    (10 periods an episode: a phase carried over a reset would be off by half a cycle)."""
    env = MicroGravityLandingEnv(condition=2)
    dithered = DitheredAdaptiveFeedforward(PERIOD, dither=DitherSettings(50e-9, 4e-3))
    plain = make_controller("adaptive", PERIOD)
    held = 1e-7  # a residual's setpoint
    for episode in range(2):
        observation, info = env.reset(seed=episode)
        for controller in (dithered, plain):
            controller.reset()
        dithered.setpoint_m[0] = held
        for k in range(10):
            plain.setpoint_m[0] = held + (50e-9 if (k // 2) % 2 == 0 else -50e-9)
            action = dithered(observation, info)
            np.testing.assert_array_equal(action, plain(observation, info))
            assert dithered.setpoint_m[0] == held
            observation, _, _, _, info = env.step(action)


def test_the_dither_is_the_tuned_one_and_refuses_what_it_cannot_run():
    """``adaptive-dither`` takes config/controllers.toml's 60 nm and 10 ms (5 control periods a
    half-cycle at 1 ms; the 10 ms period rounded to whole control periods at 4 ms: 8 ms); a bad
    amplitude or period, or one a square wave cannot switch at, is named."""
    controller = make_controller("adaptive-dither", PERIOD)
    assert controller.dither == DitherSettings(6e-8, 0.01)
    assert controller.half_period == 5
    assert make_controller("adaptive-dither", 4e-3).half_period == 1
    for amplitude, period, match in ((-1e-9, 0.01, "amplitude_m"), (1e-8, float("nan"), "period_s")):
        with pytest.raises(ValueError, match=match):
            DitherSettings(amplitude, period)
    with pytest.raises(ValueError, match="shorter than two control periods"):
        make_controller("adaptive-dither", 1e-2)


@pytest.mark.slow
@pytest.mark.parametrize("friction", [True, False])
def test_the_dither_takes_out_the_compensation_error_the_friction_leaves(friction):
    """The compensation error ``adaptive`` leaves in a slow descent is the LuGre friction's: with
    the screw's and the guide's friction (held-out `light-long`, plants drawn 1.5 times wider,
    seeds 1000-1001) the dither cuts it at least fourfold (measured: 20 and 100 times); without
    friction neither leaves 0.001 % (measured: 0.00015-0.00023 %): there is nothing for the dither
    to take out, and it adds none."""
    spec = {"randomize": "wider", "imperfections": {} if friction else {"friction": False}}
    names, seeds = ("adaptive", "adaptive-dither"), (1000, 1001)
    specs = [RunSpec("light-long", name, seed, **spec) for seed in seeds for name in names]
    results = iter(run_all(specs))  # rigs of one batch, each as it runs alone
    for seed in seeds:
        errors = {name: np.mean(np.abs(next(results).metrics.compensation_error_pct)) for name in names}
        if friction:
            assert errors["adaptive-dither"] * 4 < errors["adaptive"], (seed, errors)
        else:
            assert max(errors.values()) < 1e-3, (seed, errors)


@pytest.mark.parametrize("period", [0.0, -1e-3, float("nan"), 1.0])
def test_a_controller_refuses_a_control_period_the_rig_cannot_run(period):
    with pytest.raises(ValueError, match="control_period_s"):
        make_controller("pid", period)


def test_the_pid_kernels_read_the_drives_speed_where_the_loop_holds_it():
    """pid_actions and feedforward_actions scale their command by the loop's entry LOOP_MAX_SPEED."""
    from microg_env.controllers.pid import LOOP_MAX_SPEED
    from microg_env.interface import MAX_SPEED_M_S

    loop = make_controller("pid", PERIOD).loop()
    assert len(loop) == LOOP_MAX_SPEED + 1
    assert loop[LOOP_MAX_SPEED] == MAX_SPEED_M_S
