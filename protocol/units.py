"""Units: the report's inches, pounds, ounce-inches and degrees in SI, declared once.

Every package above `timebase` may import it (firmware_py, hil_sim, host_tools, the benches).
Multiply a value in the named unit by the constant to get SI: `24 * IN_TO_M` metres,
`45.0 * DEG` radians.
"""
from __future__ import annotations

import math

DEG = math.pi / 180.0                       # radians per degree
RPM_TO_RAD_S = 2.0 * math.pi / 60.0
G_EARTH_M_S2 = 9.80665                      # standard gravity (also defines lbf from lb)
LB_TO_KG = 0.45359237
IN_TO_M = 0.0254
LBF_TO_N = LB_TO_KG * G_EARTH_M_S2          # 4.448222 N
LBF_IN_TO_NM = LBF_TO_N * IN_TO_M           # 0.1129848 N m
LBF_FT_TO_NM = LBF_IN_TO_NM * 12.0          # 1.355818 N m
OZ_IN_TO_NM = LBF_IN_TO_NM / 16.0           # 0.00706155 N m
