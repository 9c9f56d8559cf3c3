"""One control period of N rigs, compiled: the drive's command in; sensors, reward, termination out.

Each kernel is a loop over the rigs being stepped (:mod:`microg_env.compiled`), the same code for
one rig and for a batch of them, so the single and the vector environment stay bit-identical. Each
kernel takes the rigs as an index array ``ids``
into the per-rig state arrays of :class:`~microg_env.envs.core.LandingCore` (it writes them in place)
and the ``(N, ...)`` data arrays of :mod:`microg_env.sim.physics`.
"""

from __future__ import annotations

import numpy as np

from microg_env.compiled import jit, mj_step, ufunc
from microg_env.controllers.pid import pid_actions
from microg_env.sim.model import DCMOTOR_FIELDS, slew_rate

KP, KD = DCMOTOR_FIELDS["kp"], DCMOTOR_FIELDS["kd"]

#: Why :func:`pid_periods` returned: it ran every period asked for; the episode ended; after a
#: period's physics the sensors cannot be read in the loop (a test weight came due, or the noise
#: draws ran out: the caller reads them, as the environment's step does, and finishes the period);
#: the sensors used the last of their noise draws; the PID gave a non-finite action (nothing of
#: that period ran).
RAN, ENDED, OBSERVE_HERE, NOISE_USED, NON_FINITE = range(5)


@ufunc("float64(float64, float64, float64)")
def x_reward(x_m: float, scale_m: float, limit_m: float) -> float:
    """The reward for holding x: 1 - log(1 + (x/scale)^2) / log(1 + (limit/scale)^2).

    In decades: it falls by the same amount for each decade that x grows, from ``scale`` (x's noise
    floor) to ``limit`` (the guide's half stroke), so it keeps a gradient from millimetres down to
    nanometres; it is 1 at x = 0 and 0 at the guide's end and beyond (the period that overruns the
    guide pays 0, never less), so an episode that ends early only forgoes what it would have earned.
    A NumPy ufunc: scalars or arrays.
    """
    ratio, top = x_m / scale_m, limit_m / scale_m
    return max(1.0 - np.log1p(ratio * ratio) / np.log1p(top * top), 0.0)


@jit
def drive(
    ids, positions, actions, previous_action, commands, delay, pending, command, steps, position_ref,
    drift_n_per_s, drift_dof, qfrc_applied, ctrl, dynprm, servo, slew_index, gear, ideal, max_speed,
    control_period_s, period_span_s,
):  # fmt: skip
    """Send rigs ``ids`` their speed commands for the next period: ``commands[j]`` (m/s) where
    ``commands`` has a command per rig, else the rig's action ``actions[positions[j]]`` times
    ``max_speed`` (the action's unit); the action is kept as the rig's previous one.

    The command is clipped to the drive's range and, with the control delay, swapped for the one
    sent a period earlier. The drive interpolates its position reference as a ramp at the commanded
    speed: the dcmotor's slew limiter (``dynprm[..., slew_index]``) moves its setpoint, the period's
    end, at that rate; the ideal drive takes the speed itself. The balancer's drift force grows with
    the period's start time. Advances each rig's step count and reference to the period's end.
    """
    for j in range(ids.size):
        i = ids[j]
        action = actions[positions[j]]
        previous_action[i] = action
        value = commands[j] if commands.size else action * max_speed
        value = min(max(value, -max_speed), max_speed)
        if delay:
            value, pending[i] = pending[i], value
        command[i] = value
        qfrc_applied[i, drift_dof] = drift_n_per_s[i] * (steps[i] * control_period_s)
        speed = value * gear
        end = position_ref[i] + speed * period_span_s
        if ideal:
            ctrl[i, 0] = speed
        else:
            dynprm[i, servo, slew_index] = slew_rate(speed)
            ctrl[i, 0] = end
            ctrl[i, 1] = speed
        position_ref[i] = end
        steps[i] += 1


@jit
def observe(
    ids, qpos, sensordata, screw_qpos, qzs_qpos, motor_qpos, accel_adr, force_adr, gravity,
    noisy, noise, bias, resolution, normals, used,
    last_readings, fresh, accelerometer, placed_load_kg, previous_action, base_command, scales,
    control_period_s, observation, reward_x, reward_scale_m, x_limit_m,
    screw_low, screw_high, floor_m, codes_out, next_load, load_count, switch_height_m, height_out,
    qvel, screw_dof, qzs_dof, steps, descent, descent_weight, descent_scale_m_s, descent_limit_m_s, reward,
):  # fmt: skip
    """Read the sensors of rigs ``ids`` into their ``observation`` rows, and score and check them.

    The sensors (:class:`~microg_env.sim.sensors.SensorModel`): ruler (x), encoder (the motor's
    angle over the gear: the support's position on a rigid transmission), accelerometer (g
    removed) and pad force, each plus its bias and its noise (``noisy``; the next of each rig's
    standard normal ``normals``), ruler and encoder quantised to their ``resolution``; rates by
    backward difference (0 at a rig's first reading). The observation is
    each reading over its scale, as float32. ``reward_x[i]`` is :func:`x_reward` of the true x;
    :func:`score_descent` writes the descent's velocity error into ``descent[i, 3]``, and
    ``reward[i]`` is the period's reward: ``reward_x[i]`` weighted ``1 - descent_weight``, plus
    the descent's score weighted ``descent_weight``. ``codes_out[j]`` is the termination code
    (0: going on; 1 guide stroke, 2 screw stroke, 3 pad bottomed out).

    First, though: if some rig has no noise draw left, nothing is read and it returns -2, for the
    draws to be made (:class:`~microg_env.sim.sensors.NoiseDraws`) and the call made again; then
    the rigs whose foot has come down to their next test weight's switch height
    (``switch_height_m``; ``height_out[j]`` its height, NaN for the others): if any has, nothing is
    read and it returns -1, for the weights to be placed and the call made again. Else it returns 1
    if some rig has used up its noise draws, 0 if not.
    """
    if noisy:
        for j in range(ids.size):
            if used[ids[j]] >= normals.shape[1]:
                return -2
    due = False
    for j in range(ids.size):
        i = ids[j]
        height_out[j] = np.nan
        if next_load[i] < load_count[i]:
            height = qpos[i, screw_qpos] + qpos[i, qzs_qpos]
            if height <= switch_height_m[i, next_load[i]]:
                height_out[j] = height
                due = True
    if due:
        return -1
    exhausted = 0
    readings = np.empty(4)
    for j in range(ids.size):
        i = ids[j]
        x = qpos[i, qzs_qpos]
        screw = qpos[i, screw_qpos]
        readings[0] = x
        readings[1] = qpos[i, motor_qpos]  # the encoder: the screw's coordinate on a rigid transmission
        readings[2] = sensordata[i, accel_adr] - gravity[i]
        readings[3] = sensordata[i, force_adr]
        if noisy:
            row = used[i]
            for k in range(4):
                readings[k] = readings[k] + bias[k] + noise[k] * normals[i, row, k]
            for k in range(2):
                readings[k] = np.rint(readings[k] / resolution[k]) * resolution[k]
            used[i] = row + 1
            if row + 1 >= normals.shape[1]:
                exhausted = 1
        x_rate = 0.0
        support_velocity = 0.0
        if not fresh[i]:
            x_rate = (readings[0] - last_readings[0, i]) / control_period_s
            support_velocity = (readings[1] - last_readings[1, i]) / control_period_s
        last_readings[0, i] = readings[0]
        last_readings[1, i] = readings[1]
        accelerometer[i] = readings[2]
        fresh[i] = False
        raw = (
            readings[0], x_rate, readings[1], support_velocity, readings[2], readings[3],
            readings[1] + readings[0], placed_load_kg[i], previous_action[i], base_command[i],
        )  # fmt: skip
        for k in range(10):
            observation[i, k] = np.float32(raw[k] / scales[k])
        reward_x[i] = x_reward(x, reward_scale_m, x_limit_m)
        error = score_descent(
            descent[i], steps[i] * control_period_s, qvel[i, screw_dof] + qvel[i, qzs_dof], sensordata[i, force_adr]
        )
        reward[i] = reward_x[i]
        if descent_weight > 0.0:
            score = x_reward(error, descent_scale_m_s, descent_limit_m_s)
            reward[i] = (1.0 - descent_weight) * reward_x[i] + descent_weight * score
        code = 0
        if screw + x <= floor_m:
            code = 3
        if screw <= screw_low or screw >= screw_high:
            code = 2
        if abs(x) >= x_limit_m:
            code = 1
        codes_out[j] = code
    return exhausted


@jit
def score_descent(descent, time_s, velocity_m_s, pad_force_n):
    """The velocity error of one rig's descent at ``time_s``, m/s (0 outside a descent window),
    its state ``descent`` updated: [window start s (inf: none), lander velocity at the start (NaN:
    not yet taken), ideal descent acceleration m g / (M + m) (Table 2), the last error, 1 once the
    foot has touched the pad].

    The error is v(t) - v(t0) - a_ideal (t - t0) from the window's start t0 (``SETTLE_S`` after the
    stage's weight is placed) on: the acceleration error a - a_ideal (the compensation error
    a / a_ideal - 1 times a_ideal) integrated, so a constant bias grows steadily while the
    vibration that dominates an instant's acceleration averages out. The window closes for good
    at the first pad contact (``pad_force_n`` > 0)."""
    if pad_force_n > 0.0:
        descent[0], descent[4] = np.inf, 1.0
    error = 0.0
    if time_s >= descent[0]:
        if np.isnan(descent[1]):
            descent[0], descent[1] = time_s, velocity_m_s
        error = velocity_m_s - descent[1] - descent[2] * (time_s - descent[0])
    descent[3] = error
    return error


@jit
def tally(ids, positions, codes, steps, max_steps, reward, total, periods, codes_out, truncated, going):
    """Add one period of rigs ``ids`` (at ``positions`` of the step's outputs) to the step's sums;
    ``going[j]``: rig j neither terminated nor reached its last step. Returns how many go on."""
    count = 0
    for j in range(ids.size):
        i, p = ids[j], positions[j]
        total[p] += reward[i]
        periods[p] += 1
        codes_out[p] = codes[j]
        truncated[p] = codes[j] == 0 and steps[i] >= max_steps[i]
        going[j] = codes[j] == 0 and not truncated[p]
        count += going[j]
    return count


@jit
def state(
    ids, qpos, qvel, qacc, sensordata, actuator_force, qfrc_applied, screw_qpos, qzs_qpos, screw_dof, qzs_dof,
    servo, force_adr, drift_on_qzs, x_stiffness, steps, control_period_s, accelerometer, placed_load_kg,
    next_load, command, setpoint_m, reference_weight_n, reward_x, descent, out,
):  # fmt: skip
    """The true physical state of rigs ``ids``, one row of ``out`` per rig in the order of the
    environment's ``STATE_KEYS``."""
    for j in range(ids.size):
        i = ids[j]
        x = qpos[i, qzs_qpos]
        deviation = -x_stiffness[i] * x
        if drift_on_qzs:
            deviation = deviation + qfrc_applied[i, qzs_dof]
        row = out[j]
        row[0] = steps[i] * control_period_s
        row[1] = x
        row[2] = qpos[i, screw_qpos] + x
        row[3] = qvel[i, screw_dof] + qvel[i, qzs_dof]
        row[4] = qacc[i, screw_dof] + qacc[i, qzs_dof]
        row[5] = accelerometer[i]
        row[6] = qpos[i, screw_qpos]
        row[7] = qvel[i, screw_dof]
        row[8] = deviation
        row[9] = sensordata[i, force_adr]
        row[10] = placed_load_kg[i]
        row[11] = next_load[i] - 1
        row[12] = command[i]
        row[13] = setpoint_m[i] if setpoint_m.size else 0.0
        row[14] = actuator_force[i, servo]
        row[15] = deviation / reference_weight_n[i]
        row[16] = reward_x[i]
        row[17] = descent[i, 3]


@jit
def finish_period(tally_args, sums, state_args, states, rewards, row):
    """The rest of one period of one rig after its sensors were read: :func:`tally` (``tally_args``
    then the step's ``sums``: total, periods, codes, truncated, going) of the one period, its reward
    (the step's mean, as :meth:`~microg_env.envs.core.LandingCore.step` returns it) into
    ``rewards[row]`` and its :func:`state` into ``states[row]``; whether its episode ended."""
    total, periods, codes, truncated, _ = sums
    total[0] = 0.0
    periods[0] = 0
    tally(*tally_args, *sums)
    rewards[row] = total[0] / periods[0]
    state(*state_args, states[row : row + 1])
    return codes[0] != 0 or truncated[0]


@jit
def speed_inputs(ids, ctrl, qvel, motor_dof, gear, command, previous_speed, gainprm, servo, step_s):
    """The drive's speed input for the coming physics step of rigs ``ids`` (``drive_scheme``
    ``"midpoint"``): the one that makes the dcmotor's speed loop, kp (r - theta) + kd (w_r - w),
    read the reference r, the angle theta and the speed w at the middle of the step whose current
    it filters, though MuJoCo gives it the reference at the step's end and the angle and speed at
    its start.

    With h the step, w the motor's speed now (``qvel`` of ``motor_dof`` times ``gear``), a the
    acceleration over the last step (from ``previous_speed``; 0 after a reset, NaN there) and
    w_r the period's commanded speed (``command``, m/s, times ``gear``): the middle's speed is
    w + h a (the next step's, on MuJoCo's semi-implicit steps), its angle theta + h/2 (w + h a) and
    its reference r_end - h/2 w_r, so the input is w_r - h / (2 Ti) (w_r + w + h a) - h a with
    1 / Ti = kp / kd of each rig (``gainprm``)."""
    for j in range(ids.size):
        i = ids[j]
        speed = qvel[i, motor_dof] * gear
        previous = previous_speed[i]
        acceleration = 0.0 if np.isnan(previous) else (speed - previous) / step_s
        previous_speed[i] = speed
        reference = command[i] * gear
        middle = speed + step_s * acceleration
        inverse_ti = gainprm[i, servo, KP] / gainprm[i, servo, KD]
        ctrl[i, 1] = reference - 0.5 * step_s * inverse_ti * (reference + middle) - step_s * acceleration


@jit
def midpoint_steps(model, data, count, speed_args):
    """``count`` physics steps of one rig (its ``MjModel`` and ``MjData`` at addresses ``model``
    and ``data``), the drive's speed input set before each (:func:`speed_inputs`, ``speed_args``)."""
    for _ in range(count):
        speed_inputs(*speed_args)
        mj_step(model, data)


@jit
def pid_periods(
    count, model, data, frame_skip, ids, actions, observation, pid_args, drive_args, observe_args, tally_args, sums,
    state_args, missing, states, rewards, row, midpoint, speed_args,
):  # fmt: skip
    """Up to ``count`` control periods of rig ``ids[0]`` (its ``MjModel`` and ``MjData`` at
    addresses ``model`` and ``data``) driven by a PID, each what the environment's step does with
    the PID's action: :func:`~microg_env.controllers.pid.pid_actions` of the ``observation``
    (``pid_args`` after the observation and rig) into ``actions[0]``, clipped; :func:`drive`;
    ``frame_skip`` physics steps (with ``midpoint``, :func:`midpoint_steps` of ``speed_args``);
    :func:`observe` (the sensors ``missing`` read 0) and :func:`finish_period` into rows ``row``,
    ``row + 1``, ... The argument tuples are those of each kernel, ``ids``, ``actions`` and
    ``observation`` among them. Returns the periods finished and why it stopped (:data:`RAN` ...)."""
    out = np.empty(1, dtype=np.float32)  # the PID's action, float32 as the action space's
    for n in range(count):
        pid_actions(observation, ids, *pid_args, out)
        value = np.float64(out[0])
        if not np.isfinite(value):
            actions[0] = value  # for the caller's error
            return n, NON_FINITE
        actions[0] = min(max(value, -1.0), 1.0)
        drive(*drive_args)
        if midpoint:
            midpoint_steps(model, data, frame_skip, speed_args)
        else:
            for _ in range(frame_skip):
                mj_step(model, data)
        result = observe(*observe_args)
        if result < 0:
            return n, OBSERVE_HERE
        for k in missing:
            observation[ids[0], k] = 0.0
        ended = finish_period(tally_args, sums, state_args, states, rewards, row + n)
        if result == 1:
            return n + 1, NOISE_USED
        if ended:
            return n + 1, ENDED
    return count, RAN
