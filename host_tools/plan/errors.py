"""The planner's one error: what was refused (`what`: path, reach, bounds, grid, file...) and why; and the one
test of a number read from a problem file."""
from __future__ import annotations

import math
from typing import Optional


class PlanError(ValueError):
    def __init__(self, what: str, reason: str) -> None:
        super().__init__(f"{what}: {reason}")
        self.what = what
        self.reason = reason


def finite(value: object) -> Optional[float]:
    """`value` as a float if it is a finite number, else None: a bool, text, an integer too large for a float or an
    infinity are not numbers in a problem file."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None
