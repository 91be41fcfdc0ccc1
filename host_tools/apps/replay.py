"""`aspod replay FILE`: a recorded session re-simulated, and where it first diverges.

The capture's section comment holds the world it was recorded against (the plant's settings,
every controller parameter, the seed). Replay builds that world again as a `LockstepBench` on the
simulated clock, and a fresh host runs the recorded host's commands at their recorded times: the
first transmission of each COMMAND and URGENT request, and a new handshake where the recording
has one. (Frames are not replayed as bytes: a live session's keys come from fresh nonces, so the
recorded bytes would not verify; and a replay of the bytes would prove nothing about the
controller.) The replayed world is captured too, and the two captures are compared as the
controller's output: the reply to each request, the events in order, and the telemetry frame by
frame (matched by `uptime_ms`).

* A recording on the **simulated clock** (`aspod demo --record`, `LockstepBench.record`) must
  replay exactly: every reply, event and telemetry frame equal to the bit, at the same time.
  With the same key (the bench's, unless `--key-file`) the controller's bytes are the same too,
  and the report says how many frames were identical byte for byte.
* A recording made in **real time** (`aspod sim --record`, clock `paced`) is compared within
  tolerances (`Tolerances`): a command reached the real controller some fraction of a
  millisecond into its loop, which replay cannot know, so values may differ by what a
  millisecond moves. Fields that measure the host machine rather than the controller (loop
  execution times, the real-time factor, link statistics) are not compared.

The result names the first divergence: when, which message, which field, recorded and
re-simulated values.
"""
from __future__ import annotations

import bisect
import dataclasses
import io
import math
from dataclasses import dataclass, field
from typing import Any, Optional

from protocol.link import LinkState
from protocol.reasons import Reason
from protocol.schema import Direction, Message, MsgClass
from host_tools.sessions.capture import CapturedFrame, CaptureWriter, SessionCapture, SessionInfo, WorldEvent
from host_tools.sessions.pcapng import CaptureError
from host_tools.sessions.decode import MAC_BAD, DecodedFrame, SessionDecoder, format_value
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.bench_world import apply_params
from host_tools.worlds import plant_control
from host_tools.worlds.world import AFTER_THE_WORLD, LockstepBench

BENCH_KEY = b"bench-key-0123456789abcdef"      # LockstepBench's own key (what aspod demo records with)
SUBMIT_EARLY_S = 1e-6
MAX_UNCERTAINTY_MS = 250.0     # beyond this a recording's timing says too little to compare against
UP_WAIT_S = 5.0            # a command recorded before the replay's link is up waits this long for it
# a byte's time on the replayed world's line (World's 115200 baud, 10 bits a byte): how long a frame takes to write
LINE_S_PER_BYTE = 10 / 115_200
MAX_SPAN_S = 86_400.0     # a day of simulated time: more than any session records; a later time is refused unsimulated
TAIL_S = 0.1          # replay runs this long past the recording's last frame (what came later is not compared)
# What measures the host machine or the link's own traffic, not the controller's behaviour: compared
# only on the simulated clock, where they too are deterministic.
HOST_DEPENDENT = frozenset({
    "loop_max_us", "loop_p99_us", "overruns", "tx_backlog_bytes", "timing", "rtf_recent", "lag_ms", "rtf_total",
    "arm_exec_max_us", "arm_exec_p99_us", "arm_late_max_us", "arm_overruns", "frames_rx", "frames_tx",
    "link_errors", "bytes_rx", "bytes_tx", "crc_errors", "auth_errors", "rejected", "naks_tx", "naks_rx",
    "retransmits", "srtt_us", "utc_s"})
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
    replayed_bytes: bytes = b""             # the replay's own capture, as a file would hold it
    uncertainty_ms: float = 0.0             # real time: how uncertain the recording's command times are
    mac_failures: int = 0                   # recorded frames whose MAC fails under the key given (none given: 0)

    @property
    def matches(self) -> bool:
        return self.divergence is None

    def describe(self) -> str:
        how = "to the bit" if self.exact else (f"within tolerances (the recording's command times uncertain by "
                                                 f"{self.uncertainty_ms:.1f} ms)")
        lines = [f"replayed {self.commands} commands; compared {how}: {self.replies} replies, {self.events} events, "
                 f"{self.telemetry} telemetry frames"
                 + (f" ({self.telemetry_unmatched} recorded telemetry frames had no replayed frame of the same "
                    f"uptime)" if self.telemetry_unmatched else "")]
        if self.exact and self.controller_frames:
            lines.append(f"controller frames identical byte for byte: {self.identical_bytes} of "
                         f"{self.controller_frames}")
        if self.mac_failures:
            lines.append(f"{self.mac_failures} recorded frames do not verify under the key given: the recording was "
                         f"made with another key (its commands were read without their MACs)")
        lines.append("match" if self.matches else self.divergence.describe())
        return "\n".join(lines)


@dataclass
class _Output:
    """The controller's side of a session: replies by request, events in order, telemetry by uptime; and the
    frames that show how late the writing was (`made_s`)."""
    replies: dict[tuple[int, int, int], DecodedFrame] = field(default_factory=dict)
    events: list[DecodedFrame] = field(default_factory=list)
    telemetry: dict[tuple[str, int], DecodedFrame] = field(default_factory=dict)
    segments: list[bytes] = field(default_factory=list)
    written: list[tuple[float, float]] = field(default_factory=list)   # (time written, how late), by time
    session_starts: list[DecodedFrame] = field(default_factory=list)   # the HelloReplies that began one

    def made_s(self, reply: DecodedFrame, asked_s: float) -> float:
        """When the controller made `reply` to a request recorded at `asked_s`: when it was written, less how late
        the writing was then (the first frame at or after it that shows it: `_writing_lags`), never before the
        request."""
        at = bisect.bisect_left(self.written, (reply.time_s,))
        lag_s = self.written[at][1] if at < len(self.written) else 0.0
        return reply.time_s - min(lag_s, max(0.0, reply.time_s - asked_s))


@dataclass
class _Action:
    time_s: float
    message: Optional[Message]              # None: a new handshake (or a world event, below)
    world_event: Optional[dict] = None      # something done to the plant outside the link
    offset: int = 0                         # where it is in the capture: actions at one time keep this order
    request: Optional[tuple[int, int, int]] = None     # a command's (session, class, seq): its reply's key
    line_s: float = 0.0                     # a command's own time on the line


def _split(frames: list[DecodedFrame], offsets: list[int]) -> tuple[list[_Action], _Output]:
    """The host's actions and the controller's output in a decoded session (`offsets`: each frame's in the file)."""
    actions: list[_Action] = []
    out = _Output()
    session = 0
    seen_requests: set[tuple[int, int, int]] = set()
    seen_events: set[tuple[int, int]] = set()
    hello_pending = False
    for d, offset in zip(frames, offsets):
        if d.frame is None or d.message is None:
            continue
        cls, seq, name = d.frame.cls, d.frame.seq, d.name
        if d.direction is Direction.TO_CONTROLLER:
            if name == "Hello":
                if not hello_pending:
                    actions.append(_Action(d.time_s, None, offset=offset))
                hello_pending = True
            elif cls in (MsgClass.COMMAND, MsgClass.URGENT) and (session, cls, seq) not in seen_requests:
                seen_requests.add((session, cls, seq))
                actions.append(_Action(d.time_s, d.message, offset=offset, request=(session, cls, seq),
                                       line_s=d.size * LINE_S_PER_BYTE))
            continue
        out.segments.append(d.frame.signed + d.frame.tag)
        if name == "HelloReply" and d.message.result == Reason.OK:
            session += 1
            out.session_starts.append(d)
            hello_pending = False
        elif cls in (MsgClass.COMMAND, MsgClass.URGENT):
            out.replies.setdefault((session, cls, seq), d)
        elif cls == MsgClass.EVENT and (session, seq) not in seen_events:
            seen_events.add((session, seq))
            out.events.append(d)
        elif cls == MsgClass.TELEMETRY and "uptime_ms" in d.fields():
            out.telemetry.setdefault((name, d.message.uptime_ms), d)
    out.written = _writing_lags(out)
    return actions, out


def _writing_lags(out: _Output) -> list[tuple[float, float]]:
    """(time written, how much later than usual for its kind) for the frames that show it, by time.

    On a loaded machine a simulator's frames can reach its port tens of milliseconds after the controller made
    them (the writing waits for a CPU while the world goes on), and the recording stamps them when written. A
    frame carrying the controller's uptime shows by how much: its time written less its uptime, above what that
    usually is for its kind. Telemetry comes often, so each kind's usual is its least over the session (a
    TelemetryJoints waits for the TelemetryStatus made with it, and is longer on the line); a reply's or an
    event's is the least of all, allowing for its own time on the line (LINE_S_PER_BYTE). Telemetry and replies
    are made to be sent at once; an event counts only if it was made after its session began (one made before
    waits for the session), and a frame sent again counts once, as first sent. A Heartbeat's uptime is the
    link's own, on the wall clock, not the controller's: it does not count."""
    def late_s(d: DecodedFrame) -> float:
        return d.time_s - d.message.uptime_ms / 1000.0

    telemetry = list(out.telemetry.values())
    others = [d for d in out.replies.values() if "uptime_ms" in d.fields()]
    usual: dict[str, float] = {}
    for d in telemetry:
        usual[d.name] = min(late_s(d), usual.get(d.name, math.inf))
    if not telemetry and not others:
        return []
    least = min(late_s(d) - d.size * LINE_S_PER_BYTE for d in telemetry + others)
    began = [d.time_s for d in out.session_starts]
    others += [d for d in out.events if "uptime_ms" in d.fields()
               and d.message.uptime_ms / 1000.0 + least >= max((t for t in began if t <= d.time_s), default=0.0)]
    lags = [(d.time_s, late_s(d) - usual[d.name]) for d in telemetry]
    lags += [(d.time_s, late_s(d) - d.size * LINE_S_PER_BYTE - least) for d in others]
    return sorted(lags)


@dataclass
class _Loaded:
    """A capture read whole."""
    frames: list[CapturedFrame]
    events: list[WorldEvent]
    error: Optional[CaptureError]

    @property
    def world_events(self) -> list[tuple[float, dict, int]]:
        return [(e.time_s, e.event, e.offset) for e in self.events]


def _load(capture: SessionCapture) -> _Loaded:
    items = list(capture.items())
    return _Loaded([f for f in items if isinstance(f, CapturedFrame)], [e for e in items if isinstance(e, WorldEvent)],
                   capture.error)


def _decode(capture: _Loaded, psk: Optional[bytes]) -> list[DecodedFrame]:
    decoder = SessionDecoder(psk)
    return [decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length) for f in capture.frames]


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
           tolerances: Tolerances = Tolerances()) -> ReplayReport:
    """Re-run `capture`'s host commands against a fresh world; compare; `params` override the recorded ones.

    A real-time recording is replayed twice: the first run measures when the replayed controller answered each
    command, and the second moves each command by the difference from the recorded answer, so that each runs
    when the real controller ran it (it reached the real one after the line's and the host machine's delays,
    which the recording stamps only at the port)."""
    info, info_error = capture.info, capture.info_error
    capture = _load(capture)
    if capture.error is not None:
        raise ReplayError(f"the capture breaks {capture.error}: replay needs the whole session")
    plant, recorded_params, seed = world_of(info, info_error)
    for event in capture.events:
        check_world_event(event)
    last = max((f.time_s for f in capture.frames), default=0.0)
    if not last <= MAX_SPAN_S:
        raise ReplayError(f"the capture's last frame is at {last:.6g} s: beyond {MAX_SPAN_S:g} s (a day), the most "
                          "a replay simulates")
    key = psk if psk is not None else BENCH_KEY
    decoded = _decode(capture, psk)
    actions, recorded = _split(decoded, [f.offset for f in capture.frames])
    host_commands = sum(a.message is not None for a in actions)
    # A world event after the replay's end cannot change what is compared, whenever it was recorded (a simulator
    # keeps its control endpoint after the host has gone): not redone.
    end_s = last + TAIL_S
    actions = sorted(actions + [_Action(t, None, event, offset) for t, event, offset in capture.world_events
                                if t <= end_s], key=lambda a: (a.time_s, a.offset))
    if not host_commands:
        raise ReplayError("the capture holds no host commands to replay")
    exact = info.clock == "simulated"
    world = _World(key, seed, plant, {**recorded_params, **(params or {})}, end_s=end_s)
    data, samples = world.run(actions)
    replayed_capture = _load(SessionCapture(io.BytesIO(data)))
    replayed_actions, replayed = _split(_decode(replayed_capture, key), [f.offset for f in replayed_capture.frames])
    uncertainty_ms = 0.0
    if not exact:
        uncertainty_ms = _uncertainty_ms(actions, recorded, replayed_actions, replayed)
        tolerances = dataclasses.replace(tolerances, time_ms=tolerances.time_ms + uncertainty_ms,
                                         shift_ms=tolerances.shift_ms + uncertainty_ms)
        shift = round(tolerances.shift_ms)
        wanted = frozenset(u + k for _, u in recorded.telemetry for k in range(-shift, shift + 1))
        data, samples = world.run(_aligned(actions, recorded, replayed), wanted)
        replayed_capture = _load(SessionCapture(io.BytesIO(data)))
        _, replayed = _split(_decode(replayed_capture, key), [f.offset for f in replayed_capture.frames])
    report = ReplayReport(exact=exact, commands=host_commands, replayed_bytes=data,
                          uncertainty_ms=uncertainty_ms, mac_failures=sum(d.mac == MAC_BAD for d in decoded))
    _compare(recorded, replayed, samples, report, tolerances, world.end_s - TAIL_S)
    return report


def _uncertainty_ms(actions: list[_Action], recorded: _Output, replayed_actions: list[_Action],
                    replayed: _Output) -> float:
    """How uncertain the recording is about when the real controller ran its commands, in ms: the most by which a
    recorded answer was made later after its request than the replay's was (`_Output.made_s`; at most
    MAX_UNCERTAINTY_MS). The real controller ran the command somewhere in that time; on an idle machine it is a
    millisecond or two, on a loaded one it can be tens, and the comparison's time windows widen by it."""
    asked = {a.request: a.time_s for a in replayed_actions if a.request is not None}
    worst = 0.0
    for action in actions:
        key = action.request
        if key in recorded.replies and key in replayed.replies and key in asked:
            real = recorded.made_s(recorded.replies[key], action.time_s) - action.time_s
            replay_latency = replayed.replies[key].time_s - asked[key]
            worst = max(worst, real - replay_latency)
    return min(MAX_UNCERTAINTY_MS, worst * 1e3)


@dataclass
class _World:
    """How to build the recorded world again, and run a list of actions against it."""
    key: bytes
    seed: int
    plant: PlantSettings
    params: dict[str, float]
    end_s: float

    def run(self, actions: list[_Action], sample: frozenset[int] = frozenset()) -> tuple[bytes, dict]:
        """The replayed session's capture (pcapng bytes), and at every uptime (ms) in `sample` the telemetry the
        controller would have sent then: {(message name, uptime_ms): message}."""
        bench = LockstepBench(self.key, seed=self.seed, plant=self.plant)
        samples: dict[tuple[str, int], Message] = {}
        if sample:
            bench.world.scheduler.add("replay-sampler", _sampler(bench, sample, samples), period_s=0.001,
                                      priority=AFTER_THE_WORLD)
        try:
            apply_params(bench, self.params.items())
        except ValueError as exc:
            bench.close()
            raise ReplayError(str(exc)) from None
        stream = io.BytesIO()
        stream.close = lambda: None          # keep it readable after the bench closes the capture
        bench.record(CaptureWriter(stream, SessionInfo(clock="simulated", tool="aspod replay", seed=self.seed,
                                                       settings=bench.settings())))
        try:
            for action in actions:
                _do(bench, action)
            bench.run_for(max(0.0, self.end_s - bench.clock.now()))
        finally:
            bench.close()
        return stream.getvalue(), samples


def _sampler(bench: LockstepBench, wanted: frozenset[int], into: dict):
    """A task that keeps the controller's telemetry, as it would compose it, at each uptime in `wanted`."""
    controller = bench.controller

    def step(now: float) -> float:
        uptime = controller.uptime_ms(now)
        if uptime in wanted:
            for message in (controller.telemetry(now), controller.joint_telemetry(now)):
                into[(message.spec.name, uptime)] = message
            if controller.tracker.in_use:
                into[("TelemetryTracker", uptime)] = controller.tracker_telemetry(now)
        return now + 0.001
    return step


def _do(bench: LockstepBench, action: _Action) -> None:
    if action.world_event is not None:   # done after the world's tasks at its time, as the bench did
        bench.run_for(max(0.0, action.time_s - bench.clock.now()))
        try:
            bench.redo(action.world_event)
        except ValueError as exc:
            raise ReplayError(f"world event at {action.time_s:.3f} s: {exc}") from None
        return
    # The host writes at its first poll after a submission: submit just before the recorded write (a
    # capture's times are whole nanoseconds; SUBMIT_EARLY_S is well above that and below a poll).
    due = action.time_s - SUBMIT_EARLY_S
    if due > bench.clock.now():
        bench.run_for(due - bench.clock.now())
    if action.message is None:
        bench.host.connect(bench.clock.now())
        return
    if bench.host.state is not LinkState.UP:   # in real time the handshake may end a moment later here
        bench.wait_until(lambda: bench.host.state is LinkState.UP, UP_WAIT_S)
    bench.host.submit(action.message, bench.clock.now())


def _aligned(actions: list[_Action], recorded: _Output, replayed: _Output) -> list[_Action]:
    """`actions` with each command moved by (when the recorded answer was made - the replayed answer's time), in the
    same order (`_Output.made_s`); never so early that the replayed controller would have it before the recorded
    one did: the recording stamps a command when it reached the controller's port, and the replayed one reaches
    it its own time on the line after it is written."""
    out, floor = [], 0.0
    for action in actions:
        shift = 0.0
        if action.request is not None and action.request in recorded.replies and action.request in replayed.replies:
            made_s = recorded.made_s(recorded.replies[action.request], action.time_s)
            shift = max(made_s - replayed.replies[action.request].time_s, -action.line_s)
        moved = max(floor, action.time_s + shift)
        out.append(dataclasses.replace(action, time_s=moved))
        floor = moved
    return out


def _compare(recorded: _Output, replayed: _Output, samples: dict, report: ReplayReport, tol: Tolerances,
             recorded_end_s: float) -> None:
    found: list[Divergence] = []
    for key, d in recorded.replies.items():
        report.replies += 1
        found += _differ(d, replayed.replies.get(key), report.exact, tol)
    unused = [e for e in replayed.events if report.exact or e.name not in HOST_MESSAGES]
    for index, d in enumerate(recorded.events):
        if not report.exact and d.name in HOST_MESSAGES:     # the recording machine's slowness, not the controller's
            continue
        report.events += 1
        if report.exact:
            found += _differ(d, replayed.events[index] if index < len(replayed.events) else None, True, tol)
            continue
        # in real time, events a few milliseconds apart may come in another order: take the replayed one that fits
        near = [e for e in unused if e.name == d.name and abs(_uptime(e) - _uptime(d)) <= tol.time_ms]
        fits = next((e for e in near if not _differ(d, e, False, tol)), None)
        if fits is None:
            found += _differ(d, near[0] if near else None, False, tol)
        else:
            unused.remove(fits)
    extra = replayed.events[len(recorded.events):] if report.exact else unused
    extra = [e for e in extra if e.time_s <= recorded_end_s]      # after the recording ended, nothing was seen
    if extra:
        found.append(Divergence(extra[0].time_s, extra[0].name, "(event)", "(none)", "sent"))
    for key, d in recorded.telemetry.items():
        report.telemetry += 1
        if report.exact:
            found += _differ(d, replayed.telemetry.get(key), True, tol)
            continue
        # in real time: what the replayed controller showed within shift_ms of that uptime
        name, uptime = key
        around = [samples[(name, u)] for u in range(uptime - round(tol.shift_ms), uptime + round(tol.shift_ms) + 1)
                  if (name, u) in samples]
        found += _differ_sampled(d, samples.get(key), around, tol)
    if report.exact:
        report.controller_frames = len(recorded.segments)
        report.identical_bytes = sum(a == b for a, b in zip(recorded.segments, replayed.segments))
    if found:
        report.divergence = min(found, key=lambda dv: dv.time_s)


def _uptime(d: DecodedFrame) -> float:
    return float(d.fields().get("uptime_ms", d.time_s * 1e3))


def _differ(recorded: DecodedFrame, replayed: Optional[DecodedFrame], exact: bool,
            tol: Tolerances) -> list[Divergence]:
    """The first field in which `replayed` differs from `recorded` (a list of at most one)."""
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
            same = _close(spec_field, a, b, tol)
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
