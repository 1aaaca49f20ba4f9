"""Control-table LSB sizes of the X series as SI factors, read from the model files.

Every factor is the ``scale`` (SI per LSB) of an item in ``configs/models/`` (e-Manual control
table), read through :mod:`swerve.driver.control_table`; nothing is restated here. The X-series
models share these units, so the reference model's table gives them. Raw integers exist only at
:meth:`ServoModel.step`'s boundary; everything inside is SI.
"""
from __future__ import annotations

from swerve.driver.control_table import POSITION_MODES, REFERENCE_MODEL, OperatingMode, Reg, table_for

_T = table_for(REFERENCE_MODEL)

PULSES_PER_REV = _T.pulses_per_rev
RAD_PER_PULSE = _T[Reg.PRESENT_POSITION].scale                 # 2 pi / 4096 rad
RADPS_PER_VEL_UNIT = _T[Reg.PRESENT_VELOCITY].scale            # 0.229 rev/min
RADPS2_PER_ACC_UNIT = _T[Reg.PROFILE_ACCELERATION].scale       # 214.577 rev/min^2
AMP_PER_CURRENT_UNIT = _T[Reg.PRESENT_CURRENT].scale           # 2.69 mA
PWM_FULL_SCALE = _T[Reg.PWM_LIMIT].max                         # 885 = 100 % duty
VOLT_PER_UNIT = _T[Reg.PRESENT_INPUT_VOLTAGE].scale            # 0.1 V
#: Bus Watchdog (98) value while the watchdog is tripped.
WATCHDOG_TRIPPED = -1

# Operating Mode (11)
MODE_CURRENT = OperatingMode.CURRENT
MODE_VELOCITY = OperatingMode.VELOCITY
MODE_POSITION = OperatingMode.POSITION
MODE_EXTENDED_POSITION = OperatingMode.EXTENDED_POSITION
MODE_CURRENT_POSITION = OperatingMode.CURRENT_BASED_POSITION
MODE_PWM = OperatingMode.PWM

# Moving Status (123) bits
IN_POSITION = 0x01
PROFILE_ONGOING = 0x02
FOLLOWING_ERROR = 0x08
PROFILE_NONE, PROFILE_RECTANGULAR, PROFILE_TRIANGULAR, PROFILE_TRAPEZOIDAL = 0, 1, 2, 3

__all__ = ["PULSES_PER_REV", "RAD_PER_PULSE", "RADPS_PER_VEL_UNIT", "RADPS2_PER_ACC_UNIT",
           "AMP_PER_CURRENT_UNIT", "PWM_FULL_SCALE", "VOLT_PER_UNIT", "WATCHDOG_TRIPPED",
           "MODE_CURRENT", "MODE_VELOCITY", "MODE_POSITION", "MODE_EXTENDED_POSITION",
           "MODE_CURRENT_POSITION", "MODE_PWM", "POSITION_MODES", "IN_POSITION", "PROFILE_ONGOING",
           "FOLLOWING_ERROR", "PROFILE_NONE", "PROFILE_RECTANGULAR", "PROFILE_TRIANGULAR",
           "PROFILE_TRAPEZOIDAL"]
