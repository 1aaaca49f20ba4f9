"""Servos and a tyre-contact body stepped together in one compiled loop.

With tyre contact the body's reactions load the drive shafts and, with a supply resistance, the
servos' currents sag the bus voltage: every tick of every servo depends on the body's last step,
so the ticks cannot run servo after servo (:meth:`RobotPhysics.traces` is ``None``). Stepped
tick by tick from Python (:meth:`RobotPhysics.step_body` after each servo's
:meth:`ServoModel.advance`) a tick costs some 100 µs; :func:`robot_ticks` runs up to ``n`` whole
ticks (eight :func:`servo_ticks`, the backlash, :func:`contact_step`, the loads, the supply)
with the same operations in the same order on arrays, compiled by numba (:mod:`.jit`), so it
gives the same bits as the Python ticks. Without numba it is not used (:data:`ROBOT_TICKS` is
``None``) and the ticks run one by one.

Array layout (one row per servo, in the order of :attr:`RobotPhysics.servos`, which is the
order the supply sums their currents in):

- ``FLOATS``: the float state of :func:`servo_ticks` (current, speed, angle, filters, profile,
  integral, temperature, duty, held goal, goal, friction torque, overload timer);
- ``INTS``: its integer and boolean state (profile ongoing and type, wrap, started, holding,
  stuck, reported bits).
"""
from __future__ import annotations

import numpy as np

from . import body, contact, motor, protection, servo_model
from . import units as u
from .contact import contact_step
from .body import _se2_step
from .jit import compiled
from .servo_model import servo_ticks

#: Columns of the float state array (see module docstring).
FLOATS = ("current", "speed", "angle", "fy", "fdy", "ry", "rdy", "ppos", "pvel", "pacc", "integral", "temp",
          "duty", "hold", "goal_pulse", "friction_torque", "overload_s")
#: Columns of the integer state array.
INTS = ("pongoing", "ptype", "wrap", "started", "holding", "stuck", "raised")
#: Column of the servo's direction sign (+1.0 / -1.0) in :func:`servo_ticks`'s ``inputs`` row.
SIGN_COLUMN = 11


def robot_ticks(n, dt_s, plants, inputs, homing, blocked, fs, ints, enc_off, supply, load, switched, new_goal,
                drive, steer, wheel_dir, steer_dir, center, radius, steer_off, half, backlash, has_backlash,
                supply_on, supply_v, supply_r, idle_total, kl, stiffness, mass, iz, xs, ys, limits, pose, stats,
                slip, fx, fy, flong, bits_out, present_out, vmeas_out):
    """Up to ``n`` ticks of ``dt_s`` of every servo and the contact body; returns the ticks run.

    ``plants``, ``inputs``: :func:`servo_ticks`'s constants per servo (rows); ``homing``,
    ``blocked``, ``enc_off``: per servo; ``fs``, ``ints``: the state (:data:`FLOATS`,
    :data:`INTS`); ``supply`` (V) and ``load`` (output side, N·m) per servo, updated each tick;
    ``switched``, ``new_goal``: per servo, for the first tick (then cleared). Wheels: the rows of
    their ``drive`` and ``steer`` servos, drive and steering directions (±1.0), steering centre
    (pulse), radius (m), steering offset (rad); ``half``: half the steering backlash (rad),
    ``backlash`` the wheel angles behind it (valid once ``has_backlash``). Supply: on, voltage
    (V), resistance (Ω), the servos' idle current (A). Body: lateral stiffness ratio, slip
    stiffness (N·s/m), mass (kg), yaw inertia (kg·m²), wheel positions (m), friction limits (N);
    ``pose`` ``[x, y, θ, vx, vy, ω, slip energy]``, ``stats`` ``[saturated wheel-steps,
    wheel-steps]``; ``slip``, ``fx``, ``fy``, ``flong`` get the last step's per-wheel values.
    ``bits_out`` gets the Hardware Error bits each servo raised (the run stops after a tick in
    which one did), ``present_out`` / ``vmeas_out`` the last Present Position / measured velocity.
    """
    count = plants.shape[0]
    wheels = drive.shape[0]
    unused = np.empty(1)
    speeds, angles = np.empty(wheels), np.empty(wheels)
    rad_per_pulse = u.RAD_PER_PULSE
    ran = 0
    for ran in range(1, n + 1):
        raised_any = False
        for k in range(count):
            (_, bits, fs[k, 0], fs[k, 1], fs[k, 2], fs[k, 3], fs[k, 4], fs[k, 5], fs[k, 6], fs[k, 7], fs[k, 8],
             fs[k, 9], pongoing, ptype, fs[k, 10], fs[k, 11], fs[k, 12], wrap, started, holding, fs[k, 13],
             fs[k, 14], stuck, fs[k, 15], fs[k, 16], raised, present, v_meas) = servo_ticks(
                1, dt_s, plants[k], inputs[k], homing[k], False, unused, False, unused, None, blocked[k] != 0,
                fs[k, 0], fs[k, 1], fs[k, 2], fs[k, 3], fs[k, 4], fs[k, 5], fs[k, 6], fs[k, 7], fs[k, 8], fs[k, 9],
                ints[k, 0] != 0, ints[k, 1], fs[k, 10], fs[k, 11], fs[k, 12], ints[k, 2], ints[k, 3] != 0,
                switched[k] != 0, new_goal[k] != 0, ints[k, 4] != 0, fs[k, 13], fs[k, 14], ints[k, 5] != 0,
                fs[k, 15], fs[k, 16], ints[k, 6], enc_off[k], supply[k], load[k])
            ints[k, 0], ints[k, 1], ints[k, 2], ints[k, 3] = pongoing, ptype, wrap, started
            ints[k, 4], ints[k, 5], ints[k, 6] = holding, stuck, raised
            switched[k] = new_goal[k] = 0
            present_out[k], vmeas_out[k] = present, v_meas
            if bits:
                bits_out[k] |= bits
                raised_any = True
        for i in range(wheels):     # RobotPhysics._wheel_rows: ground speeds, wheel angles
            d, s = drive[i], steer[i]
            speeds[i] = wheel_dir[i] * (inputs[d, SIGN_COLUMN] * (fs[d, 1] / plants[d, 0])) * radius[i]
            sign = inputs[s, SIGN_COLUMN]
            x = sign * (fs[s, 2] / plants[s, 0] / rad_per_pulse + enc_off[s])
            p = (x - float(ints[s, 2]) + float(homing[s])) - sign * enc_off[s]
            horn = steer_dir[i] * (p - center[i]) * rad_per_pulse - steer_off[i]
            if half > 0.0:          # the wheel stays until the horn takes up the free play
                wheel = backlash[i] if has_backlash else horn
                lo, hi = horn - half, horn + half
                wheel = lo if lo > wheel else wheel
                wheel = hi if hi < wheel else wheel
                backlash[i] = horn = wheel
            angles[i] = horn
        if half > 0.0:
            has_backlash = True
        vx, vy, w, power, sat = contact_step(dt_s, kl, stiffness, mass, iz, pose[3], pose[4], pose[5], xs, ys,
                                             limits, speeds, angles, slip, fx, fy, flong)
        pose[6] += dt_s * power
        stats[0] += sat
        stats[1] += wheels
        pose[3], pose[4], pose[5] = vx, vy, w
        pose[0], pose[1], pose[2] = _se2_step(pose[0], pose[1], pose[2], vx, vy, w, dt_s)
        for i in range(wheels):     # the tyre's reaction loads the drive shaft
            d = drive[i]
            load[d] = wheel_dir[i] * inputs[d, SIGN_COLUMN] * radius[i] * flong[i]
        if supply_on:
            current = 0.0           # in servo order
            for k in range(count):
                current += inputs[k, SIGN_COLUMN] * fs[k, 12] * fs[k, 0]
            current += idle_total
            bus = supply_v - supply_r * current
            for k in range(count):
                supply[k] = bus
        if raised_any:
            break
    return ran


#: :func:`robot_ticks` compiled (:mod:`.jit`), or ``None`` without numba or with ``SWERVE_NO_JIT`` set.
ROBOT_TICKS = compiled(robot_ticks, depends=(servo_model.__file__, contact.__file__, body.__file__, motor.__file__,
                                             protection.__file__, *servo_model.KERNEL_SOURCES))
