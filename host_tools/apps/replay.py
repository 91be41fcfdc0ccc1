"""`aspod replay FILE`: a recorded session re-simulated, and where it first diverges.

The capture's section comment holds the world it was recorded against (the plant's settings,
every controller parameter, the seed). Replay builds that world again as a `LockstepBench` on the
simulated clock, and a fresh host does on the link what the recorded host did: the first
transmission of each COMMAND and URGENT request at its recorded time, whatever the request is (a
session's close too), a new handshake where the recording has one, and silence where the recorded
host was silent: after its last frame, and through any gap longer than its heartbeats allow, the
replayed host sends nothing (no heartbeat either), so the controller's link-loss fault comes in the
replay as it came in the recording. (Frames are not replayed as bytes: a live session's keys come
from fresh nonces, so the recorded bytes would not verify; and a replay of the bytes would prove
nothing about the controller.) The replayed world is captured too, and the controller's output is
compared: the reply to each request, the events in order, and the telemetry frame by frame (matched
by `uptime_ms`).

* A recording on the **simulated clock** (`aspod demo --record`, `LockstepBench.record`) must
  replay exactly: every reply, event and telemetry frame equal to the bit, at the same time.
  With the same key (the bench's, unless `--key-file`) the controller's bytes are the same too,
  and the report says how many frames were identical byte for byte.
* A recording made in **real time** (`aspod sim --record`, clock `paced`) ran its world on
  simulated time paced to the wall clock, and its link on the wall clock itself. The capture shows
  how the two ran against each other (the controller's Heartbeats carry the link's time, its
  TelemetryStatus and Status the real-time factor): replay gives its link a clock of its own that
  runs against the world's as the recording's did (`worlds/link_time.py`), and widens its time
  tolerances by the factor where the world ran faster than real time. A real-time recording that
  does not show its factor is refused: replay cannot judge its timing. The rest is compared within
  tolerances (`Tolerances`): a command reached the real controller some fraction of a millisecond
  into its loop, which replay cannot know, so values may differ by what a millisecond moves. Fields
  that measure the host machine rather than the controller (loop execution times, the real-time
  factor, link statistics) are not compared.

The capture is read as a stream, never whole: a first pass checks it and takes the figures that
need all of it, then each run reads it again in step with the simulation, holding only a window
of it (`LOOKAHEAD_S` ahead, `JUDGE_S` behind). The result names the first divergence: when, which
message, which field, recorded and re-simulated values.
"""
from __future__ import annotations

import dataclasses
import heapq
import itertools
import math
import struct
import tempfile
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, BinaryIO, Iterator, Optional, Sequence, Union

from firmware_py.uart import BAUD_RATES
from protocol.link import LinkState
from protocol.reasons import Reason
from protocol.reliable import seq_delta
from protocol.schema import Direction, Message, MsgClass
from host_tools.progress import Progress
from host_tools.sessions.capture import CaptureWriter, SessionCapture, SessionInfo, WorldEvent
from host_tools.sessions.decode import MAC_BAD, DecodedFrame, SessionDecoder, format_value
from host_tools.sessions.pcapng import NANOSECONDS, nanoseconds
from host_tools.sessions.segments import SegmentCutter
from host_tools.worlds import plant_control
from host_tools.worlds.bench_world import apply_params
from host_tools.worlds.link_time import LinkTime
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import AFTER_THE_WORLD, LockstepBench

BENCH_KEY = b"bench-key-0123456789abcdef"      # LockstepBench's own key (what aspod demo records with)
SUBMIT_EARLY_S = 1e-6
MAX_UNCERTAINTY_MS = 250.0     # beyond this a recording's timing says too little to compare against
# A real-time recording whose link clock is known against its world's only to worse than this (a stall of the world
# between two of its reports: `_Survey.lag_rise_ms`) is refused: replay cannot say when its link's times fell
LINK_MAP_LIMIT_MS = 100.0
UP_WAIT_S = 5.0            # a command recorded before the replay's link is up waits this long for it
BITS_PER_BYTE = 10         # 8N1: a byte's time on the line is 10 / baud (the recording's baud; 115200 by default)
DEFAULT_BAUD = 115_200
MAX_SPAN_S = 86_400.0     # a day of simulated time: more than any session records; a later time is refused unsimulated
TAIL_S = 0.1          # replay runs this long past the recording's last frame (what came later is not compared)
# The host's silence: a gap between two of the recorded host's frames longer than SILENT_HEARTBEATS of its heartbeat
# interval (as the HelloReply sets it, on the link's clock) means the host was gone or stopped, and the replayed host
# is silent through it. A host that is alive sends at least a heartbeat each interval.
SILENT_HEARTBEATS = 1.5
DEFAULT_HEARTBEAT_S = 1.0
# A real-time recording's factor (world seconds per link second) is judged between these; outside them the
# recording's timing is not something a replay can follow (aspod sim's --speed is 0.01..1000 or max).
FACTOR_RANGE = (0.001, 1000.0)
# Windows, in the world's seconds (times the tolerance scale, `_Plan.scale`): the recording is read LOOKAHEAD_S ahead
# of the simulation (at least two heartbeat intervals), and what it holds is judged once the simulation is JUDGE_S
# past it; at most MAX_HELD frames and outputs are held at once (a line carries far fewer in such a window).
LOOKAHEAD_S = 1.0
JUDGE_S = 1.0
MAX_HELD = 1 << 16
# What measures the host machine or the link's own traffic, not the controller's behaviour: compared
# only on the simulated clock, where they too are deterministic.
HOST_DEPENDENT = frozenset({
    "loop_max_us", "loop_p99_us", "overruns", "tx_backlog_bytes", "timing", "rtf_recent", "lag_ms", "rtf_total",
    "arm_exec_max_us", "arm_exec_p99_us", "arm_late_max_us", "arm_overruns", "frames_rx", "frames_tx",
    "link_errors", "bytes_rx", "bytes_tx", "crc_errors", "auth_errors", "rejected", "naks_tx", "naks_rx",
    "retransmits", "srtt_us", "utc_s",
    "last_event_seq"})   # (Closed: it counts the session's events, TimingWarnings too)
# The handshake's frames are read by their ids, so that a capture from before a change of their layout (the cookie,
# the controller's identity: issue 34) still shows where its sessions began; nothing else of them is compared.
HANDSHAKE = frozenset({"Hello", "HelloReply"})


def _handshake_ok(d: DecodedFrame) -> bool:
    """A HelloReply that accepted its Hello: its `result`, the payload's first byte, whatever its layout."""
    return d.frame.payload[:1] == bytes([int(Reason.OK)])


# Messages that report the host machine itself (a world too slow for real time): compared on the simulated clock only
HOST_MESSAGES = frozenset({"TimingWarning"})


class ReplayError(ValueError):
    """The capture cannot be replayed (no world described in it, a broken file, ...)."""


@dataclass(frozen=True)
class Tolerances:
    """How far a real-time recording may differ from its replay, per field unit (absolute), else relative."""
    time_ms: float = 25.0          # an event's or a reply's uptime_ms
    shift_ms: float = 10.0         # telemetry: what the replay showed this long before or after the same uptime
    # degC: the box's temperature is read with 0.1 degC of noise a sample (hil_sim/plant.py temp_noise_c), and a
    # reply a few ms earlier or later reads another sample: 0.5 is 3.5 sigma of two samples' difference (V: 0.02)
    by_unit: tuple[tuple[str, float], ...] = (("deg", 0.1), ("deg/s", 0.5), ("mm", 0.2), ("mm/s", 1.0),
                                              ("A", 0.25), ("V", 0.1), ("degC", 0.5), ("%", 0.5))
    relative: float = 0.02

    def allows(self, unit: str, recorded: float, replayed: float) -> bool:
        if unit == "ms":
            return abs(recorded - replayed) <= self.time_ms
        limit = dict(self.by_unit).get(unit, self.relative * max(abs(recorded), 1.0))
        rounding = 1e-6 * max(abs(recorded), abs(replayed))      # the fields are f32: 22.1 is 22.100000381...
        return abs(recorded - replayed) <= limit + rounding

    def widened(self, scale: float, uncertainty_ms: float, link_map_ms: float = 0.0) -> "Tolerances":
        """The time windows for a recording whose world ran `scale` times faster than the wall clock (at least 1:
        the host's and the line's delays, in wall time, took that many times longer in the world's), whose
        command times are uncertain by `uncertainty_ms`, and whose link clock is known against the world's to
        `link_map_ms` (`_Survey.link_map_ms`: it moves the times the link's clock sets, not the telemetry's)."""
        return dataclasses.replace(self, time_ms=self.time_ms * scale + uncertainty_ms + link_map_ms,
                                   shift_ms=self.shift_ms * scale + uncertainty_ms)


@dataclass
class Divergence:
    time_s: float
    message: str
    field: str
    recorded: Any
    replayed: Any

    def describe(self) -> str:
        return (f"first divergence at {self.time_s:.3f} s: {self.message}.{self.field}: recorded "
                f"{_shown(self.recorded)}, re-simulated {_shown(self.replayed)}")


def _shown(value: Any) -> str:
    return value if isinstance(value, str) else format_value(value)


@dataclass
class ReplayReport:
    exact: bool                             # compared to the bit (simulated clock) or within tolerances
    commands: int = 0
    replies: int = 0
    events: int = 0
    telemetry: int = 0
    telemetry_unmatched: int = 0            # real time only: recorded telemetry with no replayed uptime_ms
    identical_bytes: int = 0
    controller_frames: int = 0
    divergence: Optional[Divergence] = None
    uncertainty_ms: float = 0.0             # real time: how uncertain the recording's command times are
    link_map_ms: float = 0.0                # real time: how uncertain its link's clock is against its world's
    mac_failures: int = 0                   # recorded frames whose MAC fails under the key given (none given: 0)
    factor: Optional[tuple[float, float, float]] = None   # real time: the world's factor (overall, least, most)

    @property
    def matches(self) -> bool:
        return self.divergence is None

    def describe(self) -> str:
        how = "to the bit" if self.exact else (f"within tolerances (the recording's command times uncertain by "
                                                 f"{self.uncertainty_ms:.1f} ms, its link's clock by "
                                                 f"{self.link_map_ms:.1f} ms)")
        lines = [f"replayed {self.commands} commands; compared {how}: {self.replies} replies, {self.events} events, "
                 f"{self.telemetry} telemetry frames"
                 + (f" ({self.telemetry_unmatched} recorded telemetry frames had no replayed frame of the same "
                    f"uptime)" if self.telemetry_unmatched else "")]
        if self.factor is not None:
            overall, least, most = self.factor
            lines.append(f"the recording's world ran at {overall:.3g}x real time ({least:.3g} to {most:.3g}), its link "
                         f"on the wall clock: re-simulated so")
        if self.exact and self.controller_frames:
            lines.append(f"controller frames identical byte for byte: {self.identical_bytes} of "
                         f"{self.controller_frames}")
        if self.mac_failures:
            lines.append(f"{self.mac_failures} recorded frames do not verify under the key given: the recording was "
                         f"made with another key (its commands were read without their MACs)")
        lines.append("match" if self.matches else self.divergence.describe())
        return "\n".join(lines)


# ---- what a session's frames are to replay: the host's actions, the controller's output ----------------------

HELLO, REQUEST, WORLD_EVENT, SILENT, SPEAK = "hello", "request", "world event", "silent", "speak"
REPLY, EVENT, TELEMETRY = "reply", "event", "telemetry"


@dataclass
class _Action:
    """Something the host did (or the world had done to it) at `time_s`."""
    time_s: float
    kind: str                               # HELLO, REQUEST, WORLD_EVENT, SILENT, SPEAK
    offset: int = 0                         # where it is in the capture: actions at one time keep this order
    message: Optional[Message] = None       # a request
    world_event: Optional[dict] = None
    request: Optional[tuple[int, int, int]] = None     # a request's (session, class, seq): its reply's key
    line_s: float = 0.0                     # a request's own time on the line


@dataclass
class _Rate:
    """From `world_s` on, the recorded link's clock ran at `rate` link seconds per world second."""
    world_s: float
    rate: float


@dataclass
class _Said:
    """What the controller said that is compared: a reply (`key`: its request's), an event, a telemetry frame."""
    kind: str
    frame: DecodedFrame
    key: Any = None


class _Sorter:
    """Tells what each decoded frame of a session is, in order (`take`): a host action, a controller output to
    compare, or nothing. It keeps only the numbers the session has reached: a request, a reply or an event is
    new when its sequence number is past the last one of its kind (16-bit serial arithmetic, the link's own
    order); a telemetry frame when its uptime is past the last of its message."""

    def __init__(self, line_s_per_byte: float) -> None:
        self.line_s_per_byte = line_s_per_byte
        self.session = 0
        self.session_started_s = 0.0
        self._hello_pending = False
        self._requests: dict[int, int] = {}
        self._answered: dict[int, int] = {}
        self._event_seq: Optional[int] = None
        self._uptimes: dict[str, int] = {}

    def take(self, d: DecodedFrame, offset: int) -> Union[_Action, _Said, None]:
        if d.frame is None or (d.message is None and d.name not in HANDSHAKE):
            return None
        cls, seq, name = d.frame.cls, d.frame.seq, d.name
        if d.direction is Direction.TO_CONTROLLER:
            if name == "Hello":
                pending, self._hello_pending = self._hello_pending, True
                return None if pending else _Action(d.time_s, HELLO, offset)
            if cls in (MsgClass.COMMAND, MsgClass.URGENT) and _past(seq, self._requests, cls):
                return _Action(d.time_s, REQUEST, offset, d.message, request=(self.session, cls, seq),
                               line_s=d.size * self.line_s_per_byte)
            return None
        if name == "HelloReply" and _handshake_ok(d):
            self.session += 1
            self.session_started_s = d.time_s
            self._hello_pending = False
            self._requests.clear()
            self._answered.clear()
            self._event_seq = None
        elif cls in (MsgClass.COMMAND, MsgClass.URGENT) and _past(seq, self._answered, cls):
            return _Said(REPLY, d, (self.session, cls, seq))
        elif cls == MsgClass.EVENT and (self._event_seq is None or seq_delta(seq, self._event_seq) > 0):
            self._event_seq = seq
            return _Said(EVENT, d)
        elif cls == MsgClass.TELEMETRY and "uptime_ms" in d.fields():
            uptime = d.message.uptime_ms
            if name not in self._uptimes or uptime > self._uptimes[name]:
                self._uptimes[name] = uptime
                return _Said(TELEMETRY, d, (name, uptime))
        return None


def _past(seq: int, last: dict[int, int], cls: int) -> bool:
    """`seq` is past the last one of class `cls` (recorded in `last` if so)."""
    if cls in last and seq_delta(seq, last[cls]) <= 0:
        return False
    last[cls] = seq
    return True


def _late_s(d: DecodedFrame) -> float:
    """When a frame was written less when the controller made it (its uptime)."""
    return d.time_s - d.message.uptime_ms / 1000.0


def _host_heard(d: DecodedFrame) -> bool:
    """A frame of the host's that the controller takes as a sign of life (it parsed and, if checked, verified)."""
    return d.direction is Direction.TO_CONTROLLER and d.message is not None and d.mac != MAC_BAD


# ---- the first pass: can it be replayed, and the figures that need the whole recording ----------------------

@dataclass
class _Survey:
    """What a first pass over the recording says (`_survey`)."""
    last_s: float = 0.0                     # its last frame
    host_commands: int = 0
    mac_failures: int = 0
    heartbeat_s: float = DEFAULT_HEARTBEAT_S     # the host's heartbeat interval (link seconds)
    usual_late_s: dict[str, float] = field(default_factory=dict)   # by telemetry message: least (written - made)
    least_late_s: float = math.inf          # of telemetry and replies, less each one's time on the line
    heartbeats: list[tuple[float, float]] = field(default_factory=list)   # the first two (world s, link s)
    heartbeat_count: int = 0
    factors: list[float] = field(default_factory=lambda: [math.inf, -math.inf])     # least, most: from Heartbeats
    rtf: list[float] = field(default_factory=lambda: [math.inf, -math.inf])         # least, most: rtf_recent
    lag_samples: int = 0                    # Status and TelemetryStatus that say how late the world was
    last_heartbeat: Optional[tuple[float, float]] = None
    last_lag: Optional[tuple[float, float]] = None      # the last of those: (uptime s, lag s)
    lag_rise_at_s: float = 0.0              # the uptime of the report that showed the most rise
    last_factor: float = 1.0                # the world's seconds per link second between the last two Heartbeats
    # the link's clock against the world's is known only at those reports (`_LinkTrack`): between two, a stall of
    # the world may have fallen anywhere, and a time the link's clock sets (a link timeout) with it. How far, in ms:
    lag_rise_ms: float = 0.0                # the most the world's lag rose between two Status or TelemetryStatus
    heartbeat_drift_ms: float = 0.0         # the most the world's time between two Heartbeats ran off the rate before

    def factor(self) -> Optional[tuple[float, float, float]]:
        """The world's seconds per link second: (overall, least, most); None where the recording does not show it.
        From the controller's Heartbeats (they carry the link's time) when there are two or more; else from the
        real-time factor its Status and TelemetryStatus report (`rtf_recent`)."""
        if self.heartbeat_count >= 2 and self.factors[0] <= self.factors[1]:
            (s0, u0), (s1, u1) = self.heartbeats[0], self.last_heartbeat
            return (s1 - s0) / (u1 - u0), self.factors[0], self.factors[1]
        if self.rtf[0] <= self.rtf[1]:
            return math.sqrt(self.rtf[0] * self.rtf[1]), self.rtf[0], self.rtf[1]
        return None


def _survey(capture: SessionCapture, psk: Optional[bytes], line_s_per_byte: float) -> _Survey:
    """One pass over the recording; ReplayError for what cannot be replayed (in the order a reader would want
    to hear it: the file, then its world events, then its times)."""
    survey = _Survey()
    sorter = _Sorter(line_s_per_byte)
    decoder = SessionDecoder(psk)
    event_problem: Optional[ReplayError] = None
    order_problem = ""
    latest = -math.inf
    for item in capture.items():
        if isinstance(item, WorldEvent):
            if event_problem is None:
                try:
                    check_world_event(item)
                except ReplayError as exc:
                    event_problem = exc
            continue
        if item.time_s < latest and not order_problem:
            order_problem = (f"the frame at byte {item.offset} is stamped {item.time_s:.9g} s, before the one "
                             f"before it ({latest:.9g} s): replay follows a session in the order it was recorded")
        latest = max(latest, item.time_s)
        d = decoder.decode(item.data, item.time_s, item.link, item.direction, item.original_length)
        survey.mac_failures += d.mac == MAC_BAD
        said = sorter.take(d, item.offset)
        if isinstance(said, _Action) and said.kind == REQUEST:
            survey.host_commands += 1
        elif isinstance(said, _Said) and "uptime_ms" in said.frame.fields():
            late = _late_s(said.frame)
            if said.kind == TELEMETRY:
                survey.usual_late_s[d.name] = min(late, survey.usual_late_s.get(d.name, math.inf))
            if said.kind in (TELEMETRY, REPLY):
                survey.least_late_s = min(survey.least_late_s, late - d.size * line_s_per_byte)
        if d.message is None or d.mac == MAC_BAD:
            continue
        if d.name == "HelloReply" and d.message.result == Reason.OK and d.message.heartbeat_ms > 0:
            # as a host takes it (protocol/host_link.py): at most a third of the link timeout
            survey.heartbeat_s = min(d.message.heartbeat_ms, max(10, d.message.link_timeout_ms / 3)) / 1000.0
        elif d.name == "Heartbeat" and d.direction is Direction.TO_HOST:
            _heartbeat(survey, d.time_s, d.message.uptime_ms / 1000.0)
        elif d.name in ("Status", "TelemetryStatus") and d.message.rtf_recent > 0:
            survey.rtf[0] = min(survey.rtf[0], d.message.rtf_recent)
            survey.rtf[1] = max(survey.rtf[1], d.message.rtf_recent)
            survey.lag_samples += 1
            _lag(survey, d.message.uptime_ms / 1000.0, d.message.lag_ms / 1000.0)
    if capture.error is not None:
        raise ReplayError(f"the capture breaks {capture.error}: replay needs the whole session")
    if event_problem is not None:
        raise event_problem
    if order_problem:
        raise ReplayError(order_problem)
    survey.last_s = max(latest, 0.0)
    if not survey.last_s <= MAX_SPAN_S:
        raise ReplayError(f"the capture's last frame is at {survey.last_s:.6g} s: beyond {MAX_SPAN_S:g} s (a day), "
                          "the most a replay simulates")
    if not survey.host_commands:
        raise ReplayError("the capture holds no host commands to replay")
    return survey


def _lag(survey: _Survey, uptime_s: float, lag_s: float) -> None:
    """A Status or TelemetryStatus: the world was `lag_s` late at `uptime_s`."""
    last = survey.last_lag
    if last is not None and uptime_s > last[0] and (lag_s - last[1]) * 1000.0 > survey.lag_rise_ms:
        survey.lag_rise_ms = (lag_s - last[1]) * 1000.0     # a rise: a stall, somewhere between (catching up is steady)
        survey.lag_rise_at_s = uptime_s
    if last is None or uptime_s > last[0]:
        survey.last_lag = (uptime_s, lag_s)


def _heartbeat(survey: _Survey, world_s: float, link_s: float) -> None:
    """A controller Heartbeat: the link's time (`link_s`) when the world's was `world_s`."""
    last = survey.last_heartbeat
    if last is not None and not (world_s > last[0] and link_s > last[1]):
        return                  # no time passed on one of the clocks: nothing measured (a resent or odd frame)
    if last is not None:
        factor = (world_s - last[0]) / (link_s - last[1])
        if survey.factors[0] <= survey.factors[1]:      # against the rate before: what this interval ran off it
            before = survey.last_factor
            drift_ms = abs(world_s - last[0] - before * (link_s - last[1])) * 1000.0
            survey.heartbeat_drift_ms = max(survey.heartbeat_drift_ms, drift_ms)
        survey.last_factor = factor
        survey.factors[0], survey.factors[1] = min(survey.factors[0], factor), max(survey.factors[1], factor)
    if len(survey.heartbeats) < 1:
        survey.heartbeats.append((world_s, link_s))
    survey.last_heartbeat = (world_s, link_s)
    survey.heartbeat_count += 1


# ---- the plan: the world to build and how to follow the recording's time ------------------------------------

@dataclass
class _Plan:
    key: bytes
    seed: int
    plant: PlantSettings
    params: dict[str, float]
    baud: int
    exact: bool
    survey: _Survey
    end_s: float
    scale: float = 1.0                      # the tolerances' time scale: the world's factor where above 1
    factor: Optional[tuple[float, float, float]] = None
    speed: Optional[float] = None           # the speed the world was paced at (None: as fast as it could, or unsaid)

    @property
    def lookahead_s(self) -> float:
        silence = SILENT_HEARTBEATS * self.survey.heartbeat_s * (self.factor[2] if self.factor else 1.0)
        return max(LOOKAHEAD_S * self.scale, 2 * silence)

    @property
    def judge_s(self) -> float:
        return JUDGE_S * self.scale


def world_of(info: Optional[SessionInfo], why_not: str = "") -> tuple[PlantSettings, dict[str, float], int]:
    """The plant settings, parameters and seed a capture was recorded with; ReplayError if it does not say
    (`why_not`: why the capture's description did not read, when `info` is None)."""
    if info is None:
        raise ReplayError(f"the capture does not describe its session: {why_not}" if why_not else
                          "the capture does not describe its session (not written by aspod)")
    if "plant" not in info.settings or "params" not in info.settings:
        raise ReplayError(f"the capture was recorded by {info.tool or 'a tool'} without the world it ran against; "
                          "record with aspod sim --record or aspod demo --record")
    if not info.same_schema:
        raise ReplayError(info.schema_mismatch())
    try:
        plant = PlantSettings.from_dict(info.settings["plant"])
    except ValueError as exc:
        raise ReplayError(f"the capture's plant settings: {exc}") from None
    params = info.settings["params"]
    if not isinstance(params, dict):
        raise ReplayError("the capture's parameters are not a mapping of names to numbers")
    for name, value in params.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not -1e300 < value < 1e300:
            raise ReplayError(f"the capture's parameter {str(name)[:60]!r} is {str(value)[:60]}, not a number "
                              "a parameter can be")
    return plant, {str(k): float(v) for k, v in params.items()}, int(info.seed or 0)


def _baud(info: SessionInfo) -> int:
    """The line's baud the session was recorded at (aspod sim keeps it in the settings; a bench's is 115200)."""
    baud = info.settings.get("baud", DEFAULT_BAUD)
    if isinstance(baud, bool) or baud not in BAUD_RATES:
        raise ReplayError(f"the capture's baud {str(baud)[:60]} is not one of {', '.join(map(str, BAUD_RATES))}")
    return int(baud)


def check_world_event(event: WorldEvent) -> None:
    """ReplayError when a world event does not parse or the live control endpoint would refuse it
    (`plant_control.check_world_event`): a replay without it would report a divergence it caused itself."""
    if event.error:
        raise ReplayError(f"{event.error}: replay cannot do it again")
    where = f"world event {event.index} (at byte {event.offset})"
    if not 0.0 <= event.time_s <= math.inf:
        raise ReplayError(f"{where} is at {event.time_s:.6g} s: before the session started (0 s)")
    try:
        plant_control.check_world_event(event.event)
    except ValueError as exc:
        raise ReplayError(f"{where} is refused: {exc}") from None


def replay(capture: SessionCapture, *, psk: Optional[bytes] = None, params: dict[str, float] | None = None,
           tolerances: Tolerances = Tolerances(), output: Optional[BinaryIO] = None,
           shown: Optional[Progress] = None) -> ReplayReport:
    """Re-run `capture`'s host actions against a fresh world; compare; `params` override the recorded ones; the
    replayed session's capture goes to `output` (a binary stream) if given; `shown` follows the simulated time
    replayed, of the recording's up to its last frame (twice that for a real-time recording: it runs twice).

    A real-time recording is replayed twice: the first run measures when the replayed controller answered each
    command, and the second moves each command by the difference from the recorded answer, so that each runs
    when the real controller ran it (it reached the real one after the line's and the host machine's delays,
    which the recording stamps only at the port)."""
    if capture.error is not None:       # its very first block
        raise ReplayError(f"the capture breaks {capture.error}: replay needs the whole session")
    info = capture.info
    plant, recorded_params, seed = world_of(info, capture.info_error)
    exact = info.clock == "simulated"
    baud = _baud(info)
    survey = _survey(capture, psk, BITS_PER_BYTE / baud)
    plan = _Plan(psk if psk is not None else BENCH_KEY, seed, plant, {**recorded_params, **(params or {})}, baud,
                 exact, survey, end_s=survey.last_s + TAIL_S)
    if not exact:
        plan.factor = survey.factor()
        if plan.factor is None:
            raise ReplayError("the recording does not show how fast its world ran against the wall clock (no two "
                              "controller Heartbeats, no Status or TelemetryStatus with rtf_recent): replay cannot "
                              "judge a real-time session's timing without it")
        if not FACTOR_RANGE[0] <= plan.factor[1] <= plan.factor[2] <= FACTOR_RANGE[1]:
            raise ReplayError(f"the recording's world ran at {plan.factor[1]:.3g} to {plan.factor[2]:.3g} times real "
                              f"time, outside {FACTOR_RANGE[0]:g}..{FACTOR_RANGE[1]:g}: replay cannot follow its "
                              "timing")
        plan.scale = max(1.0, plan.factor[2])
        speed = info.settings.get("speed")
        if isinstance(speed, (int, float)) and not isinstance(speed, bool) and 0 < speed < math.inf:
            plan.speed = float(speed)
    report = ReplayReport(exact=exact, commands=survey.host_commands, mac_failures=survey.mac_failures,
                          factor=plan.factor)
    if not exact:
        _link_map_ms(survey, plan)      # refused before any run if it is too uncertain
    if shown is not None:
        shown.total = plan.end_s * (1 if exact else 2)
    if exact:
        _followed(_Run(plan, capture, psk, report, tolerances, output), shown, 0.0).go()
        return report
    with tempfile.TemporaryFile() as shifts:
        measured = _followed(_Run(plan, capture, psk, None, tolerances, None, shifts_out=shifts), shown, 0.0)
        measured.go()
        report.uncertainty_ms = min(MAX_UNCERTAINTY_MS, measured.worst_ms)
        report.link_map_ms = _link_map_ms(survey, plan)
        shifts.seek(0)
        _followed(_Run(plan, capture, psk, report, tolerances.widened(plan.scale, report.uncertainty_ms,
                                                                      report.link_map_ms), output, shifts_in=shifts),
                  shown, plan.end_s).go()
    return report


def _followed(run: "_Run", shown: Optional[Progress], base_s: float) -> "_Run":
    """`run`, its simulated clock followed by `shown` from `base_s` on (the runs before it)."""
    if shown is not None:
        shown.follow(run.bench.clock.now, base_s)
    return run


def _link_map_ms(survey: _Survey, plan: _Plan) -> float:
    """How far the recording's link clock is known against its world's, in the world's ms (`_Survey.lag_rise_ms`):
    ReplayError beyond LINK_MAP_LIMIT_MS."""
    if _LinkTrack(survey, plan.speed).by_lag:
        uncertain_ms = survey.lag_rise_ms * plan.speed
        shown = f"its lag rose by {uncertain_ms:.0f} ms of its time between two reports (to uptime " \
                f"{survey.lag_rise_at_s:.3f} s)"
    else:
        uncertain_ms = survey.heartbeat_drift_ms
        shown = f"its time ran {uncertain_ms:.0f} ms off its rate between two Heartbeats"
    if uncertain_ms > LINK_MAP_LIMIT_MS:
        raise ReplayError(f"the recording's world stalled: {shown}, and where in that stretch the stall fell the "
                          "recording cannot show; replay cannot time what the link's clock set to within "
                          f"{LINK_MAP_LIMIT_MS:g} ms. Record on a quieter machine, or with telemetry on (its reports "
                          "narrow the stretch)")
    return uncertain_ms


# ---- the recorded link's clock against the world's --------------------------------------------------------

class _LinkTrack:
    """How the recording's link clock (the wall clock) ran against its world, from what its controller said, as
    rate points (`_Rate`) one at a time (`take`). `LinkTime` follows them in the replay.

    A world paced at `speed` is due on the wall clock at (its time) / speed from an anchor, and reached each moment
    late by the lag its Status and TelemetryStatus report (`lag_ms`, at their uptime): the wall clock then read
    uptime / speed + lag. Between two such reports the link ran at 1 / speed + (the change in lag) / (the world
    time between): the world's stalls under load and its catching up are followed to the report (20 Hz with
    telemetry on). (A lag past 0.5 s is given up, the world paced anew from there: where the lag seems to fall
    faster than a world can catch up, the rate is taken as 1 / speed.) A world run as fast as it can (`--speed
    max`), or one whose frames carry no lag, is followed by the controller's Heartbeats, which carry the link's
    own time (once a wall second): the rate between two of them. With neither, the rates the reports give
    (`rtf_recent`)."""

    def __init__(self, survey: _Survey, speed: Optional[float]) -> None:
        self.by_lag = speed is not None and survey.lag_samples >= 2
        self.by_heartbeats = not self.by_lag and survey.heartbeat_count >= 2
        self._per_world = 0.0 if speed is None else 1.0 / speed
        self._last: Optional[tuple[float, float]] = None      # the last point taken: (world s, lag or link s)

    def take(self, d: DecodedFrame) -> Optional[_Rate]:
        if d.message is None or d.mac == MAC_BAD or d.direction is not Direction.TO_HOST:
            return None
        reports = d.name in ("Status", "TelemetryStatus") and d.message.rtf_recent > 0
        if self.by_lag and reports:
            return self._point(d.message.uptime_ms / 1000.0, d.message.lag_ms / 1000.0, d.message.rtf_recent)
        if self.by_heartbeats and d.name == "Heartbeat":
            return self._point(d.time_s, d.message.uptime_ms / 1000.0)
        if not (self.by_lag or self.by_heartbeats) and reports:
            return _Rate(d.time_s, 1.0 / d.message.rtf_recent)
        return None

    def _point(self, world_s: float, value_s: float, rtf: float = 0.0) -> Optional[_Rate]:
        last = self._last
        if last is not None and world_s <= last[0]:
            return None                         # no world time between (a frame resent, or out of order)
        self._last = (world_s, value_s)
        if last is None:
            return None
        change = (value_s - last[1]) / (world_s - last[0])
        if self.by_heartbeats:
            return _Rate(last[0], change) if change > 0 else None
        rate = self._per_world + change
        if rate <= 0:       # the lag given up (past the pacer's 0.5 s): the stretch ran as the world's last second
            return _Rate(last[0], 1.0 / rtf if rtf > 0 else self._per_world)
        return _Rate(last[0], rate)

    def finish(self) -> Optional[_Rate]:
        """After the last report (a paced world's): its pace. The last rate measured was that of the stretch
        before the report, a stall or a catching up, which ended with it; held beyond, it would run the link's
        clock (a Close's answer, a link timeout) as fast or as slow as that stretch ran."""
        if self.by_lag and self._last is not None:
            return _Rate(self._last[0], self._per_world)
        return None

    def first_rate(self, factor: tuple[float, float, float]) -> float:
        """The link's rate before the first point: as paced, or as the whole recording ran."""
        return self._per_world if self.by_lag else 1.0 / factor[0]


# ---- a run: the recording read in step with a re-simulation of it -----------------------------------------

_SHIFT = struct.Struct("<d")
Record = Union[_Action, _Said, _Rate, float]     # a float: every frame stamped before it has been read


class _Run:
    """One re-simulation of the recording. The recording is read in step with it, `lookahead_s` ahead; the
    host's actions are done at their times (moved by the shifts of the first run, `shifts_in`); the controller's
    output, recorded and replayed, is compared as the simulation passes it (`_Comparison`), or, in the first run
    of a real-time recording (`shifts_out`), only measured: when each command's answer came, against when the
    recorded one was made (`_Answers`)."""

    def __init__(self, plan: _Plan, capture: SessionCapture, psk: Optional[bytes], report: Optional[ReplayReport],
                 tolerances: Tolerances, output: Optional[BinaryIO], shifts_out: Optional[BinaryIO] = None,
                 shifts_in: Optional[BinaryIO] = None) -> None:
        self.plan = plan
        self._capture = capture
        self._psk = psk
        self._output = output
        self._shifts_in = shifts_in
        self._line_s_per_byte = BITS_PER_BYTE / plan.baud
        self.track = None if plan.factor is None else _LinkTrack(plan.survey, plan.speed)
        self.link_time = None if self.track is None else LinkTime(self.track.first_rate(plan.factor))
        self.bench = LockstepBench(plan.key, seed=plan.seed, plant=plan.plant, baud=plan.baud,
                                   link_time=self.link_time)
        self.comparison = None if report is None else _Comparison(plan, report, tolerances, self.bench)
        self.answers = None if shifts_out is None else _Answers(plan, shifts_out)
        self._actions: list[tuple[float, int, int, _Action]] = []     # a heap: (time, offset, order, action)
        self._order = itertools.count()
        self._rates: deque[_Rate] = deque()
        self._read_to = -math.inf           # every frame stamped before this has been read
        self._records = self._recording()
        self._floor = 0.0                   # actions are done in order: none before the one done before it
        self._last_shift = 0.0
        self.worst_ms = 0.0

    # -- reading the recording --
    def _recording(self) -> Iterator[Record]:
        """The recording's actions, compared outputs and link rates, in file order, each frame followed by its time;
        the host's silences where it fell silent."""
        plan, survey = self.plan, self.plan.survey
        sorter = _Sorter(self._line_s_per_byte)
        decoder = SessionDecoder(self._psk)
        silence_s = SILENT_HEARTBEATS * survey.heartbeat_s        # on the link's clock
        last_host: Optional[float] = None
        silent = False
        for item in self._capture.items():
            if isinstance(item, WorldEvent):
                if item.time_s <= plan.end_s:       # later, it cannot change what is compared: not redone
                    yield _Action(item.time_s, WORLD_EVENT, item.offset, world_event=item.event)
                continue
            if last_host is not None and not silent and self._link_span(last_host, item.time_s) > silence_s:
                silent = True
                yield _Action(last_host, SILENT, item.offset)
            d = decoder.decode(item.data, item.time_s, item.link, item.direction, item.original_length)
            if _host_heard(d):
                if silent:
                    silent = False
                    yield _Action(d.time_s - SUBMIT_EARLY_S, SPEAK, item.offset)
                last_host = d.time_s
            said = sorter.take(d, item.offset)
            if self.answers is not None:
                self.answers.recorded(d, said, sorter.session_started_s)
            if said is not None:
                yield said
            if plan.exact and self.comparison is not None and d.direction is Direction.TO_HOST and \
                    d.message is not None:
                self.comparison.recorded_segment(d.time_s, d.frame.signed + d.frame.tag)
            if self.track is not None:
                rate = self.track.take(d)
                if rate is not None:
                    yield rate
            yield item.time_s
        if self.track is not None:
            rate = self.track.finish()
            if rate is not None:
                yield rate
        if last_host is not None and not silent:
            yield _Action(last_host, SILENT, 1 << 62)

    def _link_span(self, from_s: float, to_s: float) -> float:
        """Link seconds between two of the recording's world times (at the link's rate now)."""
        return (to_s - from_s) * (self.link_time.rate if self.link_time is not None else 1.0)

    def _read(self, until_s: float) -> None:
        """Read the recording until every frame stamped before `until_s` has been read (or to its end)."""
        while self._read_to < until_s:
            record = next(self._records, None)
            if record is None:
                self._read_to = math.inf
                return
            if isinstance(record, float):
                self._read_to = max(self._read_to, record)
            elif isinstance(record, _Action):
                heapq.heappush(self._actions, (record.time_s, record.offset, next(self._order), record))
            elif isinstance(record, _Rate):
                self._rates.append(record)
            elif self.comparison is not None:
                self.comparison.recorded(record)
            held = len(self._actions) + len(self._rates) + (self.comparison.held() if self.comparison else 0)
            if held > MAX_HELD:
                raise ReplayError(f"the capture holds more than {MAX_HELD} frames within "
                                  f"{self.plan.lookahead_s + self.plan.judge_s:.3g} s of its time, more than a line "
                                  "carries: replay holds no more at once")

    # -- running the world --
    def go(self) -> None:
        bench = self.bench
        try:
            apply_params(bench, self.plan.params.items())
        except ValueError as exc:
            bench.close()
            raise ReplayError(str(exc)) from None
        writer = None
        if self._output is not None:
            writer = CaptureWriter(self._output, SessionInfo(clock="simulated", tool="aspod replay",
                                                             seed=self.plan.seed, settings=bench.settings()))
        bench.record(_Tap(self.plan, self.comparison, self.answers, writer))
        try:
            while True:
                self._read(bench.clock.now() + self.plan.lookahead_s)
                while self._actions and self._actions[0][0] >= self._read_to:
                    self._read(self._actions[0][0] + SUBMIT_EARLY_S)      # an earlier one may come yet
                if self._actions:
                    self._do(self._moved(heapq.heappop(self._actions)[3]))
                elif self._read_to == math.inf:
                    break
                else:
                    self._advance(bench.clock.now() + self.plan.judge_s)
            self._advance(self.plan.end_s)
            if self.comparison is not None:
                self.comparison.finish()
            if self.answers is not None:
                self.answers.finish()
                self.worst_ms = self.answers.worst_ms
        finally:
            bench.close()

    def _moved(self, action: _Action) -> _Action:
        """The action at the time this run does it: at its recorded time, or in the second run of a real-time
        recording moved by its shift (`_Answers`); never before the action done before it. The host's silence
        moves with its last command."""
        shift = 0.0
        if self._shifts_in is not None and action.kind == REQUEST:
            shift = self._last_shift = _SHIFT.unpack(self._shifts_in.read(_SHIFT.size))[0]
        elif self._shifts_in is not None and action.kind == SILENT:
            shift = self._last_shift
        moved = max(self._floor, action.time_s + shift)
        self._floor = moved
        return action if moved == action.time_s else dataclasses.replace(action, time_s=moved)

    def _advance(self, to_s: float) -> None:
        """Run the world to `to_s`, a window at a time: the recording read `lookahead_s` ahead of it, the link's
        rate set as the recording's was, what is behind judged."""
        bench = self.bench
        while True:
            now = bench.clock.now()
            self._follow_rate(now)
            target = min(to_s, now + self.plan.judge_s)
            if self._rates and now < self._rates[0].world_s < target:
                target = self._rates[0].world_s
            self._read(target + self.plan.lookahead_s)
            if target > now:
                bench.run_for(target - now)
            now = bench.clock.now()
            if self.comparison is not None:
                self.comparison.judge(now)
            if self.answers is not None:
                self.answers.judge(now)
            if now >= to_s:
                self._follow_rate(now)
                return

    def _follow_rate(self, now: float) -> None:
        """The link's rate from `now` on: the recording's last before it."""
        while self._rates and self._rates[0].world_s <= now:
            self.link_time.set_rate(now, self._rates.popleft().rate)

    def _do(self, action: _Action) -> None:
        bench = self.bench
        # The host writes at its first poll after a submission: submit just before the recorded write (a
        # capture's times are whole nanoseconds; SUBMIT_EARLY_S is well above that and below a poll). It falls
        # silent just after its last frame: on the link's own clock its polls fall between the world's
        # milliseconds, so one poll later there. World events are done after the world's tasks at their time, as
        # the bench did them.
        silent_s = SUBMIT_EARLY_S + (0.0 if self.link_time is None else bench.step_s / self.link_time.rate)
        due = {WORLD_EVENT: action.time_s, SPEAK: action.time_s, SILENT: action.time_s + silent_s}.get(
            action.kind, action.time_s - SUBMIT_EARLY_S)
        if due > bench.clock.now():
            self._advance(due)
        if action.kind == WORLD_EVENT:
            try:
                bench.redo(action.world_event)
            except ValueError as exc:
                raise ReplayError(f"world event at {action.time_s:.3f} s: {exc}") from None
        elif action.kind in (SILENT, SPEAK):
            bench.host_alive = action.kind == SPEAK
        elif action.kind == HELLO:
            bench.host.connect(bench.link_clock.now())
        else:
            deadline = bench.clock.now() + UP_WAIT_S     # in real time the handshake may end a moment later here
            while bench.host.state is not LinkState.UP and bench.clock.now() < deadline:
                self._advance(min(deadline, bench.clock.now() + bench.step_s))
            bench.host.submit(action.message, bench.link_clock.now())
            if self.answers is not None:
                self.answers.asked(action)


class _Tap:
    """The replayed controller's line, as `LockstepBench.record` gives it (`write`, `note`, `close`): cut into
    frames, decoded, sorted and handed to the comparison or the measure; and written to `writer` if any."""

    def __init__(self, plan: _Plan, comparison: Optional["_Comparison"], answers: Optional["_Answers"],
                 writer: Optional[CaptureWriter]) -> None:
        self._cutters = {direction: SegmentCutter() for direction in Direction}
        self._decoder = SessionDecoder(plan.key)
        self._sorter = _Sorter(BITS_PER_BYTE / plan.baud)
        self._comparison = comparison
        self._answers = answers
        self._exact = plan.exact
        self._writer = writer

    def write(self, link: str, direction: Direction, data: bytes, time_s: float, comment: str = "") -> None:
        if self._writer is not None:
            self._writer.write(link, direction, data, time_s, comment)
        stamped = nanoseconds(time_s) / 10 ** NANOSECONDS       # the time as a capture holds it, as recorded
        for segment, length in self._cutters[direction].feed(data):
            d = self._decoder.decode(segment, stamped, link, direction, length)
            said = self._sorter.take(d, 0)
            if self._answers is not None:
                self._answers.replayed(d, said)
            if self._comparison is None:
                continue
            if isinstance(said, _Said):
                self._comparison.replayed(said)
            if self._exact and direction is Direction.TO_HOST and d.message is not None:
                self._comparison.replayed_segment(stamped, d.frame.signed + d.frame.tag)

    def note(self, event: dict, time_s: float) -> None:
        if self._writer is not None:
            self._writer.note(event, time_s)

    def close(self) -> None:
        """The output stream is its owner's to close."""


# ---- the first run's measure: when the recorded controller made each answer ---------------------------------

class _Answers:
    """For each command, in the order the run does them: when the recorded answer was made, less when the
    replayed one came (the second run moves the command by that: `_Run._moved`), and how much later the recorded
    answer was made after its request than the replayed one (the recording's uncertainty: the most of these).

    When was a recorded answer made? On a loaded machine a simulator's frames can reach its port tens of
    milliseconds after the controller made them (the writing waits for a CPU while the world goes on), and the
    recording stamps them when written. A frame carrying the controller's uptime shows by how much: its time
    written less its uptime, above what that usually is for its kind (`_Survey.usual_late_s`, the least over the
    session: a TelemetryJoints waits for the TelemetryStatus made with it, and is longer on the line); a reply's
    or an event's is the least of all, allowing for its own time on the line (`_Survey.least_late_s`). An event
    counts only if it was made after its session began (one made before waits for the session). A Heartbeat's
    uptime is the link's own, not the controller's: it does not count. The answer was made when written less the
    lag of the first frame at or after it that shows one (within `lookahead_s`; none: no lag), never before its
    request."""

    def __init__(self, plan: _Plan, out: BinaryIO) -> None:
        self.plan = plan
        self._out = out
        self._line_s_per_byte = BITS_PER_BYTE / plan.baud
        self._asked_at: dict[tuple, float] = {}          # recorded request -> its recorded time (until answered)
        self._unresolved: deque[tuple[tuple, float, float]] = deque()   # (request, asked, answer written)
        self._made: dict[tuple, tuple[float, float]] = {}   # request -> (its answer made, asked), both recorded
        self._lag: Optional[tuple[float, float]] = None  # the frames at the latest time that show a lag: (time, least)
        self._asked: deque[_Action] = deque()            # the requests this run did, in order
        self._replayed_asked: dict[tuple, float] = {}
        self._replayed_answered: dict[tuple, float] = {}
        self.worst_ms = 0.0

    # -- the recording --
    def recorded(self, d: DecodedFrame, said: Union[_Action, _Said, None], session_started_s: float) -> None:
        if isinstance(said, _Action):
            if said.kind == REQUEST:
                self._asked_at[said.request] = said.time_s
                while len(self._asked_at) > MAX_HELD:                      # requests never answered
                    del self._asked_at[next(iter(self._asked_at))]
            return
        if self._lag is not None and d.time_s > self._lag[0]:
            self._settle()                      # no more frames at that time: the least lag there is known
        if isinstance(said, _Said) and said.kind == REPLY and said.key in self._asked_at:
            self._unresolved.append((said.key, self._asked_at.pop(said.key), d.time_s))
        lag = self._shown_lag(said, session_started_s)
        if lag is not None:
            self._lag = (d.time_s, lag if self._lag is None else min(lag, self._lag[1]))
        while self._unresolved and self._unresolved[0][2] < d.time_s - self.plan.lookahead_s:
            key, asked, written = self._unresolved.popleft()
            self._made[key] = (written, asked)            # nothing showed a lag within the window: none

    def _shown_lag(self, said: Union[_Action, _Said, None], session_started_s: float) -> Optional[float]:
        if not isinstance(said, _Said) or "uptime_ms" not in said.frame.fields():
            return None
        d, survey = said.frame, self.plan.survey
        if said.kind == TELEMETRY:
            return _late_s(d) - survey.usual_late_s.get(d.name, _late_s(d))
        if said.kind == EVENT and d.message.uptime_ms / 1000.0 + survey.least_late_s < session_started_s:
            return None                         # made before its session began: it waited for the session
        return _late_s(d) - d.size * self._line_s_per_byte - survey.least_late_s

    def _settle(self) -> None:
        at, lag_s = self._lag
        self._lag = None
        while self._unresolved and self._unresolved[0][2] <= at:
            key, asked, written = self._unresolved.popleft()
            self._made[key] = (written - min(lag_s, max(0.0, written - asked)), asked)

    # -- the replay --
    def asked(self, action: _Action) -> None:
        self._asked.append(action)

    def replayed(self, d: DecodedFrame, said: Union[_Action, _Said, None]) -> None:
        if isinstance(said, _Action) and said.kind == REQUEST:
            self._replayed_asked[said.request] = d.time_s
        elif isinstance(said, _Said) and said.kind == REPLY:
            self._replayed_answered.setdefault(said.key, d.time_s)

    def judge(self, now: float) -> None:
        """The shifts of the requests done whose answers are known (or will not come), in the order done."""
        while self._asked:
            action = self._asked[0]
            key = action.request
            if not (key in self._made and key in self._replayed_answered) and \
                    now < action.time_s + self.plan.lookahead_s + self.plan.judge_s:
                return
            self._asked.popleft()
            shift = 0.0
            made = self._made.pop(key, None)
            answered = self._replayed_answered.pop(key, None)
            asked = self._replayed_asked.pop(key, None)
            if made is not None and answered is not None:
                shift = max(made[0] - answered, -action.line_s)
                if asked is not None:
                    self.worst_ms = max(self.worst_ms, ((made[0] - made[1]) - (answered - asked)) * 1e3)
            self._out.write(_SHIFT.pack(shift))

    def finish(self) -> None:
        if self._lag is not None:
            self._settle()
        while self._unresolved:
            key, asked, written = self._unresolved.popleft()
            self._made[key] = (written, asked)
        self.judge(math.inf)


# ---- the comparison, a window at a time ----------------------------------------------------------------------

class _Comparison:
    """The controller's output, recorded and replayed, compared as the simulation passes it: each recorded reply,
    event and telemetry frame is judged once the simulation is far enough past it to have made its counterpart,
    and what is judged is let go. Only what came before the recording's last frame counts (after it, nothing was
    seen)."""

    def __init__(self, plan: _Plan, report: ReplayReport, tol: Tolerances, bench: LockstepBench) -> None:
        self.plan = plan
        self.report = report
        self.tol = tol
        self.exact = plan.exact
        self._end_s = plan.survey.last_s
        self._replies: dict[tuple, tuple[float, DecodedFrame]] = {}        # recorded, by key: (judged at, frame)
        self._replayed_replies: dict[tuple, DecodedFrame] = {}
        self._events: deque[DecodedFrame] = deque()                         # recorded, in order
        self._replayed_events: deque[DecodedFrame] = deque()
        self._telemetry: deque[tuple[float, tuple, DecodedFrame]] = deque()    # recorded: (judged at, key, frame)
        self._replayed_telemetry: dict[tuple, DecodedFrame] = {}
        self._segments: deque[tuple[float, bytes]] = deque()            # exact: the controller's frames, in order
        self._replayed_segments: deque[tuple[float, bytes]] = deque()
        self._shift = round(tol.shift_ms)
        self._wanted: Counter = Counter()       # real time: uptimes (ms) to sample, by how many frames want each
        self._samples: dict[tuple[str, int], Message] = {}
        if not self.exact:
            bench.world.scheduler.add("replay-sampler", self._sampler(bench), period_s=0.001,
                                      priority=AFTER_THE_WORLD)

    def held(self) -> int:
        return (len(self._replies) + len(self._replayed_replies) + len(self._events) + len(self._replayed_events)
                + len(self._telemetry) + len(self._replayed_telemetry) + len(self._segments)
                + len(self._replayed_segments) + len(self._samples) // 3)

    def _found(self, found: list[Divergence]) -> None:
        for divergence in found:
            first = self.report.divergence
            if first is None or divergence.time_s < first.time_s:
                self.report.divergence = divergence

    # -- the recording's side --
    def recorded(self, said: _Said) -> None:
        d, judge_s = said.frame, self.plan.judge_s
        if said.kind == REPLY:
            if said.key not in self._replies and not self.exact and "uptime_ms" in d.fields():
                uptime = int(d.fields()["uptime_ms"])      # its snapshot: the controller's state then (`judge`)
                self._wanted.update(range(uptime - self._shift, uptime + self._shift + 1))
            self._replies.setdefault(said.key, (d.time_s + judge_s, d))
        elif said.kind == EVENT:
            if self.exact or d.name not in HOST_MESSAGES:   # the recording machine's slowness, not the controller's
                self._events.append(d)
        elif self.exact:
            self._telemetry.append((d.time_s + judge_s, said.key, d))
        else:
            uptime = said.key[1]
            self._wanted.update(range(uptime - self._shift, uptime + self._shift + 1))
            self._telemetry.append(((uptime + self._shift + 1) / 1000.0, said.key, d))

    def recorded_segment(self, time_s: float, segment: bytes) -> None:
        self._segments.append((time_s, segment))
        self._pair_segments()

    # -- the replay's side --
    def replayed(self, said: _Said) -> None:
        d = said.frame
        if said.kind == REPLY:
            self._replayed_replies.setdefault(said.key, d)
        elif said.kind == EVENT:
            if self.exact or d.name not in HOST_MESSAGES:
                self._replayed_events.append(d)
        elif self.exact:
            self._replayed_telemetry.setdefault(said.key, d)

    def replayed_segment(self, time_s: float, segment: bytes) -> None:
        self._replayed_segments.append((time_s, segment))
        self._pair_segments()

    def _pair_segments(self, now: float = -math.inf) -> None:
        """The controller's frames, recorded and replayed, paired in order and compared byte for byte; one that
        finds no pair within `2 * judge_s` is let go (a recorded one counted, not identical)."""
        while self._segments and self._replayed_segments:
            self.report.controller_frames += 1
            self.report.identical_bytes += self._segments.popleft()[1] == self._replayed_segments.popleft()[1]
        while self._segments and self._segments[0][0] + 2 * self.plan.judge_s <= now:
            self._segments.popleft()
            self.report.controller_frames += 1
        while self._replayed_segments and self._replayed_segments[0][0] + 2 * self.plan.judge_s <= now:
            self._replayed_segments.popleft()

    def _sampler(self, bench: LockstepBench):
        """A task that keeps the controller's telemetry, as it would compose it, at each uptime wanted."""
        controller, wanted, into = bench.controller, self._wanted, self._samples

        def step(now: float) -> float:
            uptime = controller.uptime_ms(now)
            if wanted[uptime] > 0:
                for message in (controller.telemetry(now), controller.joint_telemetry(now)):
                    into[(message.spec.name, uptime)] = message
                if controller.tracker.in_use:
                    into[("TelemetryTracker", uptime)] = controller.tracker_telemetry(now)
            return now + 0.001
        return step

    # -- judging --
    def judge(self, now: float) -> None:
        """Judge what the simulation has passed by `now`; let go of what nothing can claim any more."""
        found: list[Divergence] = []
        report, tol, exact, judge_s = self.report, self.tol, self.exact, self.plan.judge_s
        for key in [k for k, (at, d) in self._replies.items()
                    if at <= now or (k in self._replayed_replies and self._sampled(d, now))]:
            _, d = self._replies.pop(key)
            report.replies += 1
            found += _differ(d, self._replayed_replies.pop(key, None), exact, tol, self._around(d))
        for key in [k for k, d in self._replayed_replies.items() if d.time_s + 2 * judge_s <= now]:
            del self._replayed_replies[key]      # an answer to nothing recorded: not compared
        found += self._judge_events(now)
        while self._telemetry and self._telemetry[0][0] <= now:
            _, key, d = self._telemetry.popleft()
            report.telemetry += 1
            if exact:
                found += _differ(d, self._replayed_telemetry.pop(key, None), True, tol)
                continue
            # in real time: what the replayed controller showed within shift_ms of that uptime
            name, uptime = key
            window = range(uptime - self._shift, uptime + self._shift + 1)
            around = [self._samples[(name, u)] for u in window if (name, u) in self._samples]
            found += _differ_sampled(d, self._samples.get(key), around, tol)
            self._wanted.subtract(window)
        if exact:
            for key in [k for k, d in self._replayed_telemetry.items() if d.time_s + 2 * judge_s <= now]:
                del self._replayed_telemetry[key]
            self._pair_segments(now)
        else:
            keep_from = min([self._telemetry[0][1][1] if self._telemetry else math.inf] +
                            [_uptime(d) for _, d in self._replies.values() if "uptime_ms" in d.fields()]) - self._shift
            for key in [k for k in self._samples if k[1] < keep_from]:
                del self._samples[key]
            for uptime in [u for u, n in self._wanted.items() if n <= 0]:
                del self._wanted[uptime]
        self._found(found)

    def _sampled(self, d: DecodedFrame, now: float) -> bool:
        """Whether the replay is past the window of `d`'s uptime (real time; always on the simulated clock)."""
        return self.exact or "uptime_ms" not in d.fields() or now * 1000.0 > _uptime(d) + self._shift

    def _around(self, d: DecodedFrame) -> list[Message]:
        """Real time: what the replayed controller's telemetry showed within `shift_ms` of a recorded reply's
        uptime (its wants let go of); [] on the simulated clock or for a reply without an uptime."""
        if self.exact or "uptime_ms" not in d.fields():
            return []
        uptime = int(d.fields()["uptime_ms"])
        window = range(uptime - self._shift, uptime + self._shift + 1)
        self._wanted.subtract(window)
        return [m for (name, u), m in self._samples.items() if u in window]

    def _judge_events(self, now: float) -> list[Divergence]:
        found: list[Divergence] = []
        tol, judge_s = self.tol, self.plan.judge_s
        if self.exact:      # the same events in the same order: paired as they come
            while self._events and self._replayed_events:
                self.report.events += 1
                found += _differ(self._events.popleft(), self._replayed_events.popleft(), True, tol)
            while self._events and self._events[0].time_s + judge_s <= now:
                self.report.events += 1
                found += _differ(self._events.popleft(), None, True, tol)
        else:   # in real time, events a few milliseconds apart may come in another order: take one that fits
            while self._events and max(self._events[0].time_s, _uptime(self._events[0]) / 1e3) + judge_s <= now:
                d = self._events.popleft()
                self.report.events += 1
                near = [e for e in self._replayed_events
                        if e.name == d.name and abs(_uptime(e) - _uptime(d)) <= tol.time_ms]
                fits = next((e for e in near if not _differ(d, e, False, tol)), None)
                if fits is None:
                    found += _differ(d, near[0] if near else None, False, tol)
                else:
                    self._replayed_events.remove(fits)
        while self._replayed_events and self._replayed_events[0].time_s + 2 * judge_s <= now:
            found += self._extra(self._replayed_events.popleft())
        return found

    def _extra(self, e: DecodedFrame) -> list[Divergence]:
        """A replayed event that no recorded one claims: a divergence if it came before the recording ended (in
        real time, by more than the time tolerance: the recorded one, made then, may have been written after the
        recording's last frame)."""
        end_s = self._end_s if self.exact else self._end_s - self.tol.time_ms / 1000.0
        return [Divergence(e.time_s, e.name, "(event)", "(none)", "sent")] if e.time_s <= end_s else []

    def finish(self) -> None:
        """The simulation is over: judge everything."""
        self.judge(math.inf)


def _uptime(d: DecodedFrame) -> float:
    return float(d.fields().get("uptime_ms", d.time_s * 1e3))


def _differ(recorded: DecodedFrame, replayed: Optional[DecodedFrame], exact: bool,
            tol: Tolerances, around: Sequence[Message] = ()) -> list[Divergence]:
    """The first field in which `replayed` differs from `recorded` (a list of at most one). In real time a reply's
    snapshot of the controller (a Status's supply_v, at its uptime) may also match what the replayed telemetry
    showed of the same field within `shift_ms` of that uptime (`around`), as telemetry does (`_differ_sampled`): a
    command a few milliseconds earlier starts a motion, and its current's draw on the supply, as much earlier."""
    if replayed is None:
        return [Divergence(recorded.time_s, recorded.name, "(frame)", "sent", "(none)")]
    if replayed.name != recorded.name:
        return [Divergence(recorded.time_s, recorded.name, "(message)", recorded.name, replayed.name)]
    if exact and replayed.time_s != recorded.time_s:
        return [Divergence(recorded.time_s, recorded.name, "(time)", f"{recorded.time_s:.6f} s",
                           f"{replayed.time_s:.6f} s")]
    mine, theirs = recorded.fields(), replayed.fields()
    for spec_field in recorded.message.spec.fields:
        name = spec_field.name
        a, b = mine[name], theirs[name]
        if exact:
            same = a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b))
        elif name in HOST_DEPENDENT:
            continue
        else:
            same = _close(spec_field, a, b, tol) or any(
                name in m.as_dict() and _close(spec_field, a, m.as_dict()[name], tol) for m in around)
        if not same:
            return [Divergence(recorded.time_s, recorded.name, name, a, b)]
    return []


def _close(spec_field, a: Any, b: Any, tol: Tolerances) -> bool:
    if isinstance(a, float) or spec_field.unit == "ms":
        return tol.allows(spec_field.unit, float(a), float(b))
    return a == b


def _bits_seen(spec_field, value: Any, values: list[Any]) -> bool:
    """A bit field (an integer without an enum: homed axes, faults, warnings, error bits) whose every bit the replay
    showed within the window: bits that change within milliseconds of each other (axes reaching their home
    switches) may never all stand together in the replay as they did in the recording."""
    if spec_field.enum is not None or not isinstance(value, int) or isinstance(value, bool):
        return False
    set_seen = clear_seen = 0
    for v in values:
        set_seen |= v
        clear_seen |= ~v
    return value & ~set_seen == 0 and ~value & ~clear_seen == 0


def _differ_sampled(recorded: DecodedFrame, at: Optional[Message], around: list[Message],
                    tol: Tolerances) -> list[Divergence]:
    """Real time: each field of a recorded telemetry frame must match what the replayed controller showed at some
    moment within `shift_ms` of the same uptime (`around`); a command that reached the real controller a
    millisecond later moves a transient, a switch reached or a mode changed, by as much."""
    if not around:
        return [Divergence(recorded.time_s, recorded.name, "(frame)", "sent", "(no such telemetry)")]
    for spec_field in recorded.message.spec.fields:
        name = spec_field.name
        if name in HOST_DEPENDENT or name == "uptime_ms":
            continue
        a = recorded.fields()[name]
        values = [m.as_dict()[name] for m in around]
        if not any(_close(spec_field, a, b, tol) for b in values) and not _bits_seen(spec_field, a, values):
            shown = (at or around[len(around) // 2]).as_dict()[name]
            return [Divergence(recorded.time_s, recorded.name, name, a, shown)]
    return []
