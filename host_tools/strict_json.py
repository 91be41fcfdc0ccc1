"""JSON text from outside read strictly: a capture's session description and world events, the simulator's
control requests, a plan's problem file, a fuzz finding.

`loads(text)` refuses with a ValueError saying why what `json.loads` would take and a caller would then trip
over: nesting deeper than MAX_DEPTH (checked before parsing, never recursed into), NaN and Infinity (not JSON),
a number beyond a float's range (1e400, read as inf) and an integer too long to convert (4,300 digits).
"""
from __future__ import annotations

import json
import math
from typing import Any

MAX_DEPTH = 32      # what comes in nests a few levels; deeper is refused, not recursed


def loads(text: str) -> Any:
    """`text` as JSON; ValueError with the reason."""
    if not _depth_ok(text):
        raise ValueError(f"nests deeper than {MAX_DEPTH} levels")
    try:
        return json.loads(text, parse_float=_finite, parse_constant=_no_constant)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not JSON: {exc.msg} at character {exc.pos}") from None
    except RecursionError:          # not reached below MAX_DEPTH; kept so that no input can raise it
        raise ValueError(f"nests deeper than {MAX_DEPTH} levels") from None
    # any other ValueError (a number refused here, an integer of 4,300 digits) says its own reason


def _depth_ok(text: str) -> bool:
    """Whether JSON `text` nests at most MAX_DEPTH brackets (counted outside strings), before it is parsed."""
    depth, in_string, escaped = 0, False, False
    for ch in text:
        if in_string:
            escaped, in_string = (False, True) if escaped else (ch == "\\", ch != '"')
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                return False
        elif ch in "]}":
            depth -= 1
    return True


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:40]}{'...' if len(text) > 40 else ''} is out of range")
    return value


def _no_constant(text: str) -> Any:
    raise ValueError(f"{text} is not a number JSON allows")
