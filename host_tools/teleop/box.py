"""`box` and `watch box`: the solar tracker's control box as a person standing at it would see it.

    box  main ON  sensor ON  feed-forward off  controller ENABLED  22.9 C  90 V bus 89.97 V
    UTC 2026-03-20 13:50:20  sun (ephemeris) az 92.57 el 4.21 deg, az +0.134 el +0.205 deg/min
                          dial             duty   a-b   a+b angle error
    axis mode   dir speed    % relay brake    %    mV     V   deg   deg
    az   SENSOR CW  ON    10.0 CW    off   10.0  +5.3 0.197 91.04 +1.53
    el   SENSOR CW  ON    10.0 CW    off   10.0 +10.8 0.197  1.02 +3.19
    pointing error 3.53 deg; relay switchings 1/1, chatter 0/0, reversals 0/0 (az/el); refusals 0
    warnings: none  (reading 0.0 s old)

(at 96 columns; on a narrower terminal the lines wrap between their parts)

Everything comes from the latest TelemetryTracker (switches, dials, relays as sent: CW, CCW or
open; brakes: on = applied, the speed switch's Brake; duties; the photocell pair's difference
a - b and sum a + b; the axis angles; the sun from the controller's ephemeris and the pointing
error; the relays' counters and the interlocks' refusals) and TelemetryStatus (the controller's
state, the box's temperature in C). TelemetryTracker
goes out only while the box is in use (main or sensor power on), so after both are switched
off the panel shows the last reading and says how old it is. Names, units and warning docs come
from the declarations (protocol/messages.py, protocol/states.py).

`pointing_error_deg` is also what `wait aligned` waits on: the angle between the focal axis
(the tracker's azimuth and elevation) and the sun, or one axis's error.
"""
from __future__ import annotations

import math
from datetime import datetime, timezone
from typing import Optional

from protocol.messages import SCHEMA
from protocol.schema import Message
from protocol.states import TRACKER_WARNING_DOCS, TrackerWarning
from protocol.units import DEG

from host_tools.teleop import format as teleop_format
from host_tools.teleop.format import INDENT, fit_parts, format_value, wrap
from host_tools.teleop.tables import Column, table_lines

AXES = ("az", "el")
_TRACKER = SCHEMA["TelemetryTracker"]
_STATUS = SCHEMA["TelemetryStatus"]
_BOX = SCHEMA["BoxState"]
_STATE_FIELD = next(f for f in _STATUS.fields if f.name == "state")
_POSITION = next(f for f in _TRACKER.fields if f.name == "main").enum
STALE_MS = 1500            # a TelemetryTracker this much older than the latest TelemetryStatus: the box is off
NO_READING = ("(no TelemetryTracker yet: it goes out while the box is in use, main or sensor power on, at the "
              "telemetry rate; `switch sensor on` shows the photocells without driving anything)")


def position_word(value: int) -> str:
    try:
        return _POSITION(value).name
    except ValueError:
        return str(value)


def relay_word(relay: int) -> str:
    return {1: "CW", -1: "CCW", 0: "open"}.get(relay, str(relay))


def warning_names(bits: int) -> list[str]:
    names = [w.name for w in TrackerWarning if w and bits & w]
    unknown = bits & ~sum(int(w) for w in TrackerWarning)
    return names + ([f"0x{unknown:x}"] if unknown else [])


def clock_set(msg: Message) -> bool:
    return msg.utc_s != 0 and not msg.warnings & TrackerWarning.NO_CLOCK


def pointing_error_deg(msg: Message, axis: Optional[str] = None) -> Optional[float]:
    """|error| of one axis (`az`, `el`), or (None) the angle between the focal axis and the sun [deg];
    None without the controller's clock (no sun to point at)."""
    if not clock_set(msg):
        return None
    if axis is not None:
        return abs(getattr(msg, f"error_{axis}"))
    az_t, el_t, az_s, el_s = (v * DEG for v in (msg.angle_az, msg.angle_el, msg.sun_az, msg.sun_el))
    c = math.cos(el_t) * math.cos(el_s) * math.cos(az_s - az_t) + math.sin(el_t) * math.sin(el_s)
    return math.acos(max(-1.0, min(1.0, c))) / DEG


def _utc(seconds: int) -> str:
    return datetime.fromtimestamp(seconds, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S")


def header_parts(msg: Message, status: Optional[Message]) -> list[str]:
    parts = [f"box  main {position_word(msg.main)}", f"sensor {position_word(msg.sensor)}",
             f"feed-forward {'on' if msg.ff_active else 'off'}"]
    if status is not None:
        parts += [f"controller {format_value(_STATE_FIELD, status.state)}", f"{status.temp_c:.1f} C"]
    parts.append(f"90 V bus {msg.motor_supply_v:.2f} V")
    return parts


def sun_parts(msg: Message) -> list[str]:
    if not clock_set(msg):
        return ["clock not set (NO_CLOCK): no sun angles, no pointing error; `clock now` sets it"]
    return [f"UTC {_utc(msg.utc_s)}", f"sun (ephemeris) az {msg.sun_az:.2f} el {msg.sun_el:.2f} deg, "
                                      f"az {msg.sun_rate_az * 60:+.3f} el {msg.sun_rate_el * 60:+.3f} deg/min"]


# The axis table's columns: each unit under its heading, so that the panel fits 80 columns.
AXIS_COLUMNS = (Column("\naxis"), Column("\nmode"), Column("\ndir"), Column("\nspeed"), Column("dial\n%", right=True),
                Column("\nrelay"), Column("\nbrake"), Column("duty\n%", right=True), Column("a-b\nmV", right=True),
                Column("a+b\nV", right=True), Column("angle\ndeg", right=True), Column("error\ndeg", right=True))


def axis_cells(msg: Message, ax: str) -> list[str]:
    """One axis's row of the panel: the cells photocells show only with the sensor power on, the error only with
    the controller's clock."""
    get = lambda what: getattr(msg, f"{what}_{ax}")   # noqa: E731
    cells_on = msg.sensor == _POSITION.ON
    return [ax, position_word(get("mode")), position_word(get("direction")), position_word(get("speed")),
            f"{get('dial'):.1f}", relay_word(get("relay")), "on" if get("brake") else "off",
            f"{get('duty') * 100:.1f}", f"{get('cell_diff') * 1000:+.1f}" if cells_on else "off",
            f"{get('cell_sum'):.3f}" if cells_on else "-", f"{get('angle'):.2f}",
            f"{get('error'):+.2f}" if clock_set(msg) else "-"]


def axis_table(msg: Message, width: int) -> list[str]:
    return table_lines(AXIS_COLUMNS, [axis_cells(msg, ax) for ax in AXES], width)


def counters_parts(msg: Message) -> list[str]:
    error = pointing_error_deg(msg)
    first = f"pointing error {error:.2f} deg;" if error is not None else "pointing error unknown (no clock);"
    return [first, f"relay switchings {msg.switchings_az}/{msg.switchings_el},",
            f"chatter {msg.chatter_az}/{msg.chatter_el},", f"reversals {msg.reversals_az}/{msg.reversals_el} (az/el);",
            f"refusals {msg.refusals}"]


def age_text(msg: Message, status: Optional[Message]) -> str:
    """How much older the reading is than the controller's latest status ('' if current)."""
    if status is None:
        return ""
    behind_ms = status.uptime_ms - msg.uptime_ms
    if behind_ms <= STALE_MS:
        return f"  (reading {max(0, behind_ms) / 1000:.1f} s old)"
    return (f"  (reading {behind_ms / 1000:.1f} s old: TelemetryTracker stops while main and sensor power "
            "are off)")


def box_block(latest: dict, detail: bool = False) -> list[str]:
    """The panel from the latest telemetry (`TelemetryCache.latest`); `detail`: each warning's doc too."""
    msg, status = latest.get("TelemetryTracker"), latest.get("TelemetryStatus")
    if msg is None:
        return [NO_READING]
    names = warning_names(msg.warnings)
    lines = [*fit_parts(header_parts(msg, status)), *fit_parts(sun_parts(msg)), *axis_table(msg, teleop_format.WIDTH),
             *fit_parts(counters_parts(msg), sep=" "), *fit_parts([f"warnings: {', '.join(names) or 'none'}",
                                                         age_text(msg, status).strip()])]
    if detail:
        for w in TrackerWarning:
            if w and msg.warnings & w:
                lines += wrap(f"{w.name}: {TRACKER_WARNING_DOCS[w]}", INDENT)
    return lines


def box_state_text(reply: Message) -> str:
    """A BoxState reply in one line: `main ON, sensor OFF; az+el MANUAL CW speed ON dial 30.0 %` (the axes
    apart when they differ)."""
    axes = {ax: (f"{position_word(getattr(reply, f'mode_{ax}'))} {position_word(getattr(reply, f'direction_{ax}'))} "
                 f"speed {position_word(getattr(reply, f'speed_{ax}'))} dial {getattr(reply, f'dial_{ax}'):.1f} %")
            for ax in AXES}
    both = f"az+el {axes['az']}" if axes["az"] == axes["el"] else "; ".join(f"{ax} {text}" for ax, text in axes.items())
    return f"main {position_word(reply.main)}, sensor {position_word(reply.sensor)}; {both}"
