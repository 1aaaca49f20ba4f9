"""Servos and the robot body stepped together in one compiled loop.

With tyre contact the body's reactions load the drive shafts and, with a supply resistance, the
servos' currents sag the bus voltage: every tick of every servo depends on the body's last step,
so the ticks cannot run servo after servo (:meth:`RobotPhysics.traces` is ``None``). Stepped
tick by tick from Python (:meth:`RobotPhysics.step_body` after each servo's
:meth:`ServoModel.advance`) a tick costs some 100 µs; :func:`robot_ticks` runs up to ``n`` whole
ticks (eight :func:`servo_ticks`, the backlash, the body, the loads, the supply) with the same
operations in the same order on arrays, compiled by numba (:mod:`.jit`), so it gives the same
bits as the Python ticks. The body is the tyre-contact one (:func:`contact_step`) or the
kinematic least-squares fit (:func:`.body.kinematic_twist`); with the kinematic body the servos
do not interact, and one call for all of them costs less than one per servo. Without numba it
is not used (:data:`ROBOT_TICKS` is ``None``).

Array layout (one row per servo, in the order of :attr:`RobotPhysics.servos`, which is the
order the supply sums their currents in), built and kept by
:class:`~swerve.emulator.physics.coupled_arrays.CoupledArrays`:

- ``fs`` (servos, :data:`FLOATS`): the float state of :func:`servo_ticks` (current, speed,
  angle, filters, profile, integral, temperature, duty, held goal, goal, friction torque,
  overload timer);
- ``ints`` (servos, :data:`INTS`): its integer and boolean state (profile ongoing and type,
  wrap, started, holding, stuck, reported bits);
- ``servo_i`` (servos, :data:`SERVO_INTS`), ``servo_f`` (servos, :data:`SERVO_FLOATS`): per-run
  inputs and the loads and supply the body updates each tick;
- ``out_i`` (servos, 2): Hardware Error bits raised, last Present Position; ``v_meas``
  (servos,): last measured velocity;
- ``wheel_i`` (wheels, 2): rows of each wheel's drive and steering servo; ``wheel_f``
  (:data:`WHEEL_FLOATS`, wheels): each wheel's frame, position, grip limit and least-squares
  columns; ``wheel_out`` (:data:`WHEEL_OUT`, wheels): the last tick's per-wheel values;
- ``body_f`` (:data:`BODY_FLOATS`,), ``flags`` (:data:`FLAGS`,): constants and switches;
  ``pose`` ``[x, y, θ, vx, vy, ω, slip energy]``, ``stats`` ``[saturated wheel-steps,
  wheel-steps]``.
"""
from __future__ import annotations

from . import body, contact, motor, protection, servo_model
from . import units as u
from .contact import contact_step
from .body import _se2_step, kinematic_twist
from .native import native
from .servo_model import servo_ticks

#: Columns of the float state array (see module docstring).
FLOATS = ("current", "speed", "angle", "fy", "fdy", "ry", "rdy", "ppos", "pvel", "pacc", "integral", "temp",
          "duty", "hold", "goal_pulse", "friction_torque", "overload_s")
#: Columns of the integer state array.
INTS = ("pongoing", "ptype", "wrap", "started", "holding", "stuck", "raised")
#: Columns of the per-servo integer inputs: Homing Offset (pulse), shaft held, mode switched, new goal.
SERVO_INTS = ("homing", "blocked", "switched", "new_goal")
#: Columns of the per-servo float inputs: encoder offset (pulse), supply (V), output-side load (N·m).
SERVO_FLOATS = ("enc_off", "supply", "load")
#: Rows of the per-wheel constants: drive and steering directions (±1.0), steering centre (pulse),
#: radius (m), steering offset (rad), position (m), grip limit (N), the least-squares operator's
#: coefficients of ``v cos δ`` and of ``v sin δ`` on ``(vx, vy, ω)``.
WHEEL_FLOATS = ("drive_dir", "steer_dir", "center", "radius", "steer_off", "x", "y", "limit",
                "cx", "cy", "cw", "sx", "sy", "sw")
#: Rows of the per-wheel results of the last tick: ground speed (m/s), wheel angle (rad), slip
#: speed (m/s), body-frame force (N), force along the wheel (N).
WHEEL_OUT = ("speed", "angle", "slip", "fx", "fy", "flong")
#: Entries of the body constants: half the steering backlash (rad), supply voltage (V) and
#: resistance (Ω), the servos' idle current (A), lateral stiffness ratio, slip stiffness (N·s/m),
#: mass (kg), yaw inertia (kg·m²).
BODY_FLOATS = ("half_backlash", "supply_v", "supply_r", "idle_total", "kl", "stiffness", "mass", "iz")
#: Entries of the switches: wheel angles behind the backlash known, supply sag on, tyre contact.
FLAGS = ("has_backlash", "supply_on", "contact")
#: Column of the servo's direction sign (+1.0 / -1.0) in :func:`servo_ticks`'s ``inputs`` row.
SIGN_COLUMN = 11


def robot_ticks(n, dt_s, plants, inputs, servo_i, servo_f, fs, ints, out_i, v_meas, wheel_i, wheel_f, backlash,
                wheel_out, body_f, flags, pose, stats, unused):
    """Up to ``n`` ticks of ``dt_s`` of every servo and the body; returns the ticks run.

    ``plants``, ``inputs``: :func:`servo_ticks`'s constants per servo (rows); the other arrays
    as the module docstring lays them out. ``servo_f``'s supply (V) and load (N·m) columns are
    updated each tick; ``servo_i``'s switched and new-goal columns are read for the first tick
    (then cleared). ``out_i``'s bits column gets (ORed) the Hardware Error bits each servo
    raised (the run stops after a tick in which one did), its Present Position column and
    ``v_meas`` the last Present Position / measured velocity. ``backlash``: the wheel angles
    behind the steering backlash (valid once ``flags[0]``). ``unused``: one float, passed to
    :func:`servo_ticks` for the traces it does not record (the kernel allocates nothing).
    """
    count = plants.shape[0]
    wheels = wheel_i.shape[0]
    speeds, angles = wheel_out[0], wheel_out[1]
    drive_dir, steer_dir, center, radius, steer_off = wheel_f[0], wheel_f[1], wheel_f[2], wheel_f[3], wheel_f[4]
    half, supply_v, supply_r, idle_total = body_f[0], body_f[1], body_f[2], body_f[3]
    has_backlash, supply_on, contact_on = flags[0] != 0, flags[1] != 0, flags[2] != 0
    rad_per_pulse = u.RAD_PER_PULSE
    ran = 0
    for ran in range(1, n + 1):
        raised_any = False
        for k in range(count):
            (_, bits, fs[k, 0], fs[k, 1], fs[k, 2], fs[k, 3], fs[k, 4], fs[k, 5], fs[k, 6], fs[k, 7], fs[k, 8],
             fs[k, 9], pongoing, ptype, fs[k, 10], fs[k, 11], fs[k, 12], wrap, started, holding, fs[k, 13],
             fs[k, 14], stuck, fs[k, 15], fs[k, 16], raised, present, vm) = servo_ticks(
                1, dt_s, plants[k], inputs[k], servo_i[k, 0], False, unused, False, unused, None, servo_i[k, 1] != 0,
                fs[k, 0], fs[k, 1], fs[k, 2], fs[k, 3], fs[k, 4], fs[k, 5], fs[k, 6], fs[k, 7], fs[k, 8], fs[k, 9],
                ints[k, 0] != 0, ints[k, 1], fs[k, 10], fs[k, 11], fs[k, 12], ints[k, 2], ints[k, 3] != 0,
                servo_i[k, 2] != 0, servo_i[k, 3] != 0, ints[k, 4] != 0, fs[k, 13], fs[k, 14], ints[k, 5] != 0,
                fs[k, 15], fs[k, 16], ints[k, 6], servo_f[k, 0], servo_f[k, 1], servo_f[k, 2])
            ints[k, 0], ints[k, 1], ints[k, 2], ints[k, 3] = pongoing, ptype, wrap, started
            ints[k, 4], ints[k, 5], ints[k, 6] = holding, stuck, raised
            servo_i[k, 2] = servo_i[k, 3] = 0
            out_i[k, 1], v_meas[k] = present, vm
            if bits:
                out_i[k, 0] |= bits
                raised_any = True
        for i in range(wheels):     # RobotPhysics._wheel_rows: ground speeds, wheel angles
            d, s = wheel_i[i, 0], wheel_i[i, 1]
            speeds[i] = drive_dir[i] * (inputs[d, SIGN_COLUMN] * (fs[d, 1] / plants[d, 0])) * radius[i]
            sign = inputs[s, SIGN_COLUMN]
            enc_off = servo_f[s, 0]
            x = sign * (fs[s, 2] / plants[s, 0] / rad_per_pulse + enc_off)
            p = (x - float(ints[s, 2]) + float(servo_i[s, 0])) - sign * enc_off
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
        if contact_on:
            vx, vy, w, power, sat = contact_step(dt_s, body_f[4], body_f[5], body_f[6], body_f[7], pose[3], pose[4],
                                                 pose[5], wheel_f[5], wheel_f[6], wheel_f[7], speeds, angles,
                                                 wheel_out[2], wheel_out[3], wheel_out[4], wheel_out[5])
            pose[6] += dt_s * power
            stats[0] += sat
            stats[1] += wheels
        else:
            vx, vy, w = kinematic_twist(wheel_f[8], wheel_f[9], wheel_f[10], wheel_f[11], wheel_f[12], wheel_f[13],
                                        speeds, angles)
        pose[3], pose[4], pose[5] = vx, vy, w
        pose[0], pose[1], pose[2] = _se2_step(pose[0], pose[1], pose[2], vx, vy, w, dt_s)
        if contact_on:
            flong = wheel_out[5]
            for i in range(wheels):     # the tyre's reaction loads the drive shaft
                d = wheel_i[i, 0]
                servo_f[d, 2] = drive_dir[i] * inputs[d, SIGN_COLUMN] * radius[i] * flong[i]
        if supply_on:
            current = 0.0           # in servo order
            for k in range(count):
                current += inputs[k, SIGN_COLUMN] * fs[k, 12] * fs[k, 0]
            current += idle_total
            bus = supply_v - supply_r * current
            for k in range(count):
                servo_f[k, 1] = bus
        if raised_any:
            break
    flags[0] = has_backlash
    return ran


#: :func:`robot_ticks` as native code (:mod:`.native`), or ``None`` without numba or with ``SWERVE_NO_JIT`` set.
ROBOT_TICKS = native(robot_ticks, ("i8", "f8", "f8[:,:]", "f8[:,:]", "i8[:,:]", "f8[:,:]", "f8[:,:]", "i8[:,:]",
                                   "i8[:,:]", "f8[:]", "i8[:,:]", "f8[:,:]", "f8[:]", "f8[:,:]", "f8[:]", "i8[:]",
                                   "f8[:]", "i8[:]", "f8[:]"),
                     depends=(servo_model.__file__, contact.__file__, body.__file__, motor.__file__,
                              protection.__file__, *servo_model.KERNEL_SOURCES))
