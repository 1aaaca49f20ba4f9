"""Open-loop PWM records simulated with the emulator's own ServoModel (sensor noise, quantisation,
irregular bus sampling), for the pure identification tests."""
from __future__ import annotations

import numpy as np

from swerve.emulator.physics import units as u
from swerve.emulator.physics.params import MotorParams, SensorParams
from swerve.emulator.physics.servo_model import ServoModel
from swerve.emulator.physics.steptest import table
from swerve.tools.tune.identify import PwmRecord

NOISE = SensorParams(position_noise_std_pulse=0.5, current_noise_std_a=0.004)


def pwm_record(params: MotorParams, gear: float, plan, *, sensors=NOISE, seed=0, dt_s=5e-4,
               mean_sample_s=1.5e-3, supply_v=12.0, friction=None) -> PwmRecord:
    """Simulate ``plan`` = [(duration_s, goal_pwm), ...] from rest and sample it irregularly.

    Each bus read lands on a physics tick; gaps between reads are ``mean_sample_s`` +- 50 %.
    ``friction``: the gearbox friction (:class:`GearFrictionParams`) of the servo, default none.
    """
    rng = np.random.default_rng(seed)
    model = ServoModel(params, gear, supply_v, sensors=sensors, rng=rng, friction=friction)
    rest = table(operating_mode=u.MODE_PWM, goal_pwm=0)
    for _ in range(20):
        model.step(dt_s, rest)
    t, pos, cur, sw_t, volts = [], [], [], [], []
    now, next_read = 0.0, 0.0
    for k, (dur, pwm) in enumerate(plan):
        if k:
            sw_t.append(now)
            volts.append(pwm / u.PWM_FULL_SCALE * supply_v)
        items = table(operating_mode=u.MODE_PWM, goal_pwm=pwm)
        for _ in range(int(round(dur / dt_s))):
            out = model.step(dt_s, items)
            now += dt_s
            if now >= next_read:
                t.append(now)
                pos.append(out["present_position"] * u.RAD_PER_PULSE)
                cur.append(out["present_current"] * u.AMP_PER_CURRENT_UNIT)
                next_read = now + mean_sample_s * rng.uniform(0.5, 1.5)
    return PwmRecord(np.array(t), np.array(pos), np.array(cur), np.array(sw_t), np.array(volts))


PLAN = [(0.05, 0), (0.15, 400), (0.1, 0), (0.15, -600), (0.1, 0)]
