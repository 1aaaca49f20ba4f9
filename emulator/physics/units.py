"""Control-table LSB sizes of the X series (dynamixel-protocol2.md §3, §5), as SI factors.

Raw integers exist only at :meth:`ServoModel.step`'s boundary; everything inside is SI.
"""
from __future__ import annotations

import math

PULSES_PER_REV = 4096
RAD_PER_PULSE = 2.0 * math.pi / PULSES_PER_REV
RADPS_PER_VEL_UNIT = 0.229 * 2.0 * math.pi / 60.0           # 0.229 rev/min
RADPS2_PER_ACC_UNIT = 214.577 * 2.0 * math.pi / 3600.0      # 214.577 rev/min^2
AMP_PER_CURRENT_UNIT = 2.69e-3                               # 2.69 mA
PWM_FULL_SCALE = 885                                         # 885 = 100 % duty
VOLT_PER_UNIT = 0.1
WATCHDOG_TRIPPED = -1

# Operating Mode (11)
MODE_CURRENT = 0
MODE_VELOCITY = 1
MODE_POSITION = 3
MODE_EXTENDED_POSITION = 4
MODE_CURRENT_POSITION = 5
MODE_PWM = 16
POSITION_MODES = (MODE_POSITION, MODE_EXTENDED_POSITION, MODE_CURRENT_POSITION)

# Moving Status (123) bits
IN_POSITION = 0x01
PROFILE_ONGOING = 0x02
FOLLOWING_ERROR = 0x08
PROFILE_NONE, PROFILE_RECTANGULAR, PROFILE_TRIANGULAR, PROFILE_TRAPEZOIDAL = 0, 1, 2, 3
