"""The serial line's capacity and the telemetry rate it can carry (docs/protocol.md, "Line timing").

An 8N1 line carries `baud / BITS_PER_BYTE` bytes a second. Telemetry is sent per message kind at
`rate_hz` (TelemetryStatus and TelemetryJoints every period, TelemetryTracker at most
`TRACKER_TELEMETRY_MAX_HZ`), and may take at most `TELEMETRY_LINE_SHARE` of the line: the rest is kept
for the commands' replies, events, heartbeats and handshake answers. A `SetTelemetryRate` asking more
is refused with `OUT_OF_RANGE` by a controller that paces its line at a baud (firmware_py/controller.py).
Above the line's capacity the link's bounded telemetry queue drops frames (a third of them and more at
50 Hz and 115200 baud), so a rate the line cannot carry is refused rather than half delivered.
"""
from __future__ import annotations

import math

from protocol.framing import COUNTER_SIZE, CRC_SIZE, HEADER_SIZE, TAG_SIZE
from protocol.messages import SCHEMA

BAUD_RATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800)
BITS_PER_BYTE = 10                 # 8N1: start + 8 data + stop
TELEMETRY_LINE_SHARE = 0.8         # of the line's bytes a second, telemetry may take at most this share
TRACKER_TELEMETRY_MAX_HZ = 10.0    # the tracker turns at most 35.2 deg/min (full duty): 10 Hz is a sample per 0.06 deg
EVERY_PERIOD = ("TelemetryStatus", "TelemetryJoints")     # sent at rate_hz each
AT_MOST_TRACKER_HZ = ("TelemetryTracker",)                 # sent at min(rate_hz, TRACKER_TELEMETRY_MAX_HZ)
MAX_RATE_HZ = SCHEMA["SetTelemetryRate"].fields[0].range[1]


def wire_bytes(payload_bytes: int) -> int:
    """The most bytes a signed frame with a payload of `payload_bytes` takes on the line: the raw frame
    (header, counter, payload, tag, CRC), COBS's worst case (one code byte per 254 bytes, and one), and the
    two 0x00 delimiters."""
    raw = HEADER_SIZE + COUNTER_SIZE + payload_bytes + TAG_SIZE + CRC_SIZE
    return raw + raw // 254 + 1 + 2


def telemetry_bytes_per_s(rate_hz: float) -> float:
    """The line bytes a second telemetry at `rate_hz` takes at most: every kind that may be sent at that rate,
    TelemetryTracker counted whether or not the control box is in use (it may be switched on later)."""
    every = sum(wire_bytes(SCHEMA[name].size) for name in EVERY_PERIOD)
    tracker = sum(wire_bytes(SCHEMA[name].size) for name in AT_MOST_TRACKER_HZ)
    return rate_hz * every + min(rate_hz, TRACKER_TELEMETRY_MAX_HZ) * tracker


def line_bytes_per_s(baud: int) -> float:
    return baud / BITS_PER_BYTE


def telemetry_budget_bytes_per_s(baud: int) -> float:
    """What telemetry may take of a line at `baud`."""
    return line_bytes_per_s(baud) * TELEMETRY_LINE_SHARE


def max_telemetry_hz(baud: int) -> int:
    """The highest whole rate_hz whose telemetry fits the line at `baud` (`telemetry_bytes_per_s` is increasing)."""
    budget = telemetry_budget_bytes_per_s(baud)
    fits = [rate for rate in range(MAX_RATE_HZ + 1) if telemetry_bytes_per_s(rate) <= budget]
    return max(fits)


def tracker_every(rate_hz: int) -> int:
    """TelemetryTracker goes with every this many periods of the others, so at most TRACKER_TELEMETRY_MAX_HZ."""
    return math.ceil(rate_hz / TRACKER_TELEMETRY_MAX_HZ - 1e-9)
