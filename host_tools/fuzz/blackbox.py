"""The black-box, stateful fuzzer: against any link URL (a pty, a TCP port, a serial device), a live `aspod sim`
or a real controller that speaks this protocol, holding its key.

It runs the handshake as a host does (a `HostLink` over a `SerialLine`) and keeps that session's counters and
sequence numbers right. Each case is a few steps drawn from a seeded generator (the same seed, the same cases):

    command   a command in sequence through the host's own sender, its payload from the grammar (boundaries,
              one beyond, NaN and infinities, broken names): it reaches the handler
    frame     a frame built by the fuzzer (link_targets.FrameRecipe): header fields, length, class, flags, MAC
              (another key, the handshake key, a flipped bit, none, a used counter), a duplicate or a gap
    replay    a frame sent earlier, again
    raw       any bytes
    hello     a Hello under the handshake key with fields from the grammar (a new nonce)
    burst     several commands written at once;  silence   no byte (not even a heartbeat) for 50-80 % of the
              controller's link timeout, which must not count it as lost

One case in `CHAIN_ONE_IN` is a sequence instead (grammar.py `draw_chain`): commands whose replies say what the
last one must carry (TrajClear and TrajPoints, then TrajRun with the count of knots held), each sent once the
reply before it has come, with what that reply said.

At the first session the fuzzer reads the target's parameter table (ParamList): its names are the grammar's
words for ParamGet and ParamSet, and after each case what the case's ParamSets changed is set back, so every case
starts from the configuration found (`TargetParams`).

The health check, every `check_every` cases (sooner when the target does not behave as a case expects: see
`run_case`): a Ping through the session answered with its token; GetStatus with the controller's uptime rising,
its commands-executed counter moved by exactly the commands that ran (those whose payload decodes, each once), and
its state changed only if a command was accepted, or into FAULT for a cause outside the cases (the arm faulting
under a motion we started, our own silence past the link timeout, the target saying it is too slow for real time).
A failed check is pinned to its case (`BlackBoxFuzzer.bisect`) and is a finding: its steps, the bytes sent and the
pauses, saved once a bug (host_tools/fuzz/findings.py). With `--target-cmd` the fuzzer starts the target itself,
restarts it after a crash, and shrinks a finding on fresh targets (host_tools/fuzz/shrink.py); a target it started
is a hang only once it has had `health_timeout_s` of its own time (host_tools/worlds/own_time.py: the wall time
less its waits for a CPU) without answering, so a busy machine is not taken for a hung target. A target it did not
start is judged on the wall clock stretched by its measured pace (`Pace`) and this process's own time.
"""
from __future__ import annotations

import json
import math
import os
import random
import select
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Callable, Optional

from protocol import auth
from protocol.framing import MAX_ENCODED, MAX_PAYLOAD
from protocol.link import LinkConfig, LinkState
from protocol.host_link import HostLink
from protocol.messages import SCHEMA, started_motions
from protocol.reliable import Outcome, ReliableSender, seq_delta
from protocol.schema import MsgClass
from protocol.states import ControllerState, Fault
from timebase import RealClock

from host_tools.client.lines import SerialLine
from host_tools.fuzz import findings as findings_mod
from host_tools.fuzz import oracles
from host_tools.fuzz.boundaries import FOLLOWS, NO_BOUNDARIES, Boundaries
from host_tools.client.params import ParamTable, read_param_table
from host_tools.fuzz.grammar import (NO_WORDS, TO_CONTROLLER, RandomDraw, Words, draw_chain, draw_payload, draw_value,
                                     pack_raw, refollow)
from host_tools.fuzz.link_targets import MACS, FrameRecipe, build
from host_tools.fuzz.shrink import minimal_steps
from host_tools.worlds.child import LOOK_S, out_of_time
from host_tools.worlds.own_time import Look, OwnTime

_CLOCK = RealClock()           # the wall clock (timebase: the one module that reads it)
# what a moving arm may latch, whatever the link does (UNCOMMANDED_MOTION too: a case may set still_deg to 0.01 deg,
# 1.5 times the drift a held mount showed after a lost link)
MOTION_FAULTS = (Fault.ENCODER | Fault.STALL | Fault.FOLLOWING_ERROR | Fault.OVER_CURRENT | Fault.HOMING_FAILED
                 | Fault.OPEN_CIRCUIT | Fault.GRIPPER | Fault.UNCOMMANDED_MOTION)
COMMANDS = tuple(s for s in TO_CONTROLLER if s.cls in (MsgClass.COMMAND, MsgClass.URGENT))
STEP_KINDS = ("command",) * 6 + ("frame",) * 5 + ("replay", "replay", "raw", "raw", "hello", "burst")
EXIT_WAIT_S = 2.0              # after the line broke, how long (of its own time) a target we started has to exit
READ_WAIT_S = 0.002            # a wait for the target's bytes looks at the line this often
READ_SIZE = 4096               # bytes taken from the line at a time (all that is there, as one read)
CHECK_EVERY = 16               # cases between two health checks while the target behaves as the cases expect
RATE_FLOOR = 0.05              # a --url target's deadlines stretch with its measured slowness, at most 1/this
RATE_KEEP = 0.7                # the weight of the rate measured before, against the latest check's
RTT_FACTOR = 50                # a --url target's deadlines are at least this many of its recent round trips
CHAIN_ONE_IN = 16              # one case in this many is a sequence of commands that builds state (grammar.draw_chain)
SILENCE_ONE_IN = 20000         # a silence (about 2 s at the default timeout) in one step of this many: at about 350
#                                steps a second, one a minute (one in 200 until 2026-11-29: most of a run)
PAUSE_ONE_IN = 64              # a pause before a step in one step of this many (one in four until 2026-11-29: the
#                                pauses took 8.4 s of a 15 s run, profiled)
SILENCE_MIN, SILENCE_MAX = 0.5, 0.8   # of the link timeout: near it, with room for this process being held up
OWN_TIME_LOOK_S = 0.5          # past a wait's bound of wall time, how often a target we started is looked at
MAX_STEPS = 6                  # a case's steps, at most
DELAY_MAX_MS = 19              # the pause before a step, at most
BURST_MIN, BURST_MAX = 2, 21   # commands in a burst
SENT_KEPT = 64                 # the frames a replay step picks from (the last sent)
FRAME_SEQS = ("duplicate", "gap", "any")   # a crafted frame's sequence number: an old one, ahead, any
OFFSET_MAX = 3                 # how far back (duplicate) or ahead (gap), at most
LENGTH_DELTA = 4               # a crafted frame's length field, off by at most this
RAW_MAX = MAX_ENCODED + 8      # a raw step's bytes, at most


class TargetGone(Exception):
    """The target stopped answering or exited: the case that did it is a finding. `broken`: the line itself failed
    (the target closed its end), rather than an answer not coming."""

    def __init__(self, message: str, broken: bool = False) -> None:
        super().__init__(message)
        self.broken = broken


@dataclass(frozen=True)
class BlackBoxSettings:
    url: str = ""                            # the link; empty: the one `command` prints (ASPOD-LINK)
    command: tuple[str, ...] = ()            # starts (and restarts) the target
    baud: int = 115200
    seconds: Optional[float] = 60.0
    cases: Optional[int] = None
    seed: int = 1
    findings: Path = Path("fuzz-findings")
    link_timeout_s: float = LinkConfig().link_timeout_s
    health_timeout_s: float = 5.0            # a Ping not answered in this long: the target is not healthy
    max_steps: int = MAX_STEPS
    skip: tuple[str, ...] = ("ParamSave",)   # commands never sent (ParamSave writes the target's own file)
    only: tuple[str, ...] = ()               # if given, the only commands sent in sequence (one handler's fuzzing)
    minimize_s: float = 60.0
    max_findings: Optional[int] = None       # stop after this many
    check_every: Optional[int] = None        # cases between two health checks (sooner when the target's behaviour
    #   changes: see `run_case`); by default CHECK_EVERY for a target we start (a failure is pinned to its case by
    #   running them again on a fresh one), 1 for a --url target (one that is gone cannot be asked again)

    def __post_init__(self) -> None:
        if not self.url and not self.command:
            raise ValueError("black-box fuzzing needs --url (a running target) or --target-cmd (one to start)")
        if self.seconds is None and self.cases is None:
            raise ValueError("black-box fuzzing needs --time or --cases")
        unknown = [n for n in self.skip + self.only if n not in {s.name for s in COMMANDS}]
        if unknown:
            raise ValueError(f"--skip/--only {', '.join(unknown)}: not a command the controller takes")
        if not self.commands:
            raise ValueError(f"--only {' '.join(self.only) or '(all)'} less --skip {' '.join(self.skip)} leaves no "
                             "command to send")
        if not 1 <= self.max_steps <= MAX_STEPS:
            raise ValueError(f"max_steps {self.max_steps}: must be 1..{MAX_STEPS}")
        if self.check_every is None:
            object.__setattr__(self, "check_every", CHECK_EVERY if self.command else 1)
        if not 1 <= self.check_every <= 1000:
            raise ValueError(f"--check-every {self.check_every}: must be 1..1000")

    @property
    def commands(self) -> list:
        """The commands sent in sequence: --only's (or all), less --skip's."""
        return [s for s in COMMANDS if s.name not in self.skip and (not self.only or s.name in self.only)]


@dataclass
class BlackBoxResult:
    cases: int = 0
    steps: int = 0
    wall_s: float = 0.0
    findings: list[str] = field(default_factory=list)
    unsaved: list[dict] = field(default_factory=list)     # findings that could not be saved (on stderr)
    restarts: int = 0
    params_put_back: int = 0     # parameters an accepted ParamSet changed, set back after its case
    checks: int = 0              # health checks made (one every `check_every` cases, or when behaviour changed)
    repeats: int = 0             # findings of a signature already found: counted in its file, not saved again
    pinning_s: float = 0.0       # of `wall_s`, spent pinning findings to their case, shrinking them, restarting
    error: str = ""

    @property
    def cases_per_s(self) -> float:
        return self.cases / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def fuzzing_cases_per_s(self) -> float:
        """Cases a second of running cases (the time spent on findings left out)."""
        fuzzing_s = self.wall_s - self.pinning_s
        return self.cases / fuzzing_s if fuzzing_s > 0 else 0.0


class _Peer:
    """What the fuzzer knows of the controller's counter: the last one of a frame it answered (a counter the
    host merely sent may have been on a frame the controller refused, and is then still fresh to it)."""

    def __init__(self, counter: int) -> None:
        self.rx_counter = counter


class Session:
    """One connection to the target: the line, the host's end of the link, the target's process if ours."""

    def __init__(self, settings: BlackBoxSettings, psk: Optional[bytes],
                 learned: Optional[Boundaries] = None) -> None:
        self.settings, self.psk, self.clock = settings, psk, RealClock()
        self.learned = Boundaries() if learned is None else learned    # fed every reply, event and telemetry frame
        self.child = None
        self.line = None
        self.url = settings.url
        if settings.command:
            from host_tools.worlds.child import ASPOD, Child
            command = settings.command
            self.child = (Child(list(command[len(ASPOD):])) if command[:len(ASPOD)] == ASPOD   # named aspod sim
                          else Child(list(command[1:]), command=command[:1]))
        try:
            self._connect()
        except BaseException:        # no session: a target we started is stopped, not left running
            self.close()
            raise

    def _connect(self) -> None:
        settings = self.settings
        if self.child is not None:
            self.url = self.child.ready("ASPOD-LINK ").split(" ", 1)[1].strip()
        url = self.url
        self.line = SerialLine(url, settings.baud)
        self.line.serial.timeout = 0          # reads take what is there; `pump` waits for it on the line's descriptor
        self._fd = self.line.serial.fileno()
        if self.child is not None and self.psk is None:   # no --key-file: the key the target made, on its next line
            key_file = self.child.ready("ASPOD-KEY ").split(" ", 1)[1].strip()
            self.psk = auth.load_key(key_file, "the target's key file (its ASPOD-KEY line)")
        if self.child is not None:
            self.child.keep_reading()      # a target's pipes, read as it writes: one full stops it (a false hang)
        self.host = HostLink(self.psk, LinkConfig(link_timeout_s=settings.link_timeout_s), on_event=self._event,
                             on_telemetry=lambda msg, now: self.learned.learn(msg))
        self.sent: list[bytes] = []
        self.started: dict[int, int] = {}      # axis -> the last motion id a command of ours started
        self.ended: dict[int, int] = {}        # axis -> the last motion id a MotionDone ended
        self.last_write_s = self.clock.now()
        self.lapsed = False                    # our own silence outlasted the link timeout since the last check
        self.accepted_counter = -1             # the host's counter on the last frame the target answered
        self.events = 0                        # events the target sent since the last health check
        self.pace = Pace()                     # a --url target's, for its deadlines
        # the own time `pump_until` judges by (the target's if ours, else this process's): one kept, its /proc read
        # at most every LOOK_S (a new one for each wait read /proc twice, 1.5 ms, several times a case: profiled)
        self._own = (self.child.own_time() if self.child is not None
                     else OwnTime(os.getpid(), self.clock, fresh_s=LOOK_S))
        self.renew()

    def renew(self) -> None:
        """A new session (the first, or after a Close of the case's ended the one before)."""
        self.closed = False
        self.host.connect(self.clock.now())
        if not self.pump_until(lambda: self.host.state is LinkState.UP, self.settings.health_timeout_s * 2):
            raise TargetGone(f"no session with {self.url} within {self.settings.health_timeout_s * 2:.0f} s "
                             f"(link {self.host.state.value})")

    def _event(self, msg, now: float) -> None:
        self.learned.learn(msg)
        self.events += 1
        self.closed |= msg.spec.name == "SessionClosed"     # a Close of ours ran (a frame we built may carry one)
        if msg.spec.name == "MotionDone":
            self.ended[msg.axis] = max(self.ended.get(msg.axis, 0), msg.motion_id)

    def note_started(self, reply) -> None:
        """The motions a MotionAccepted reply says it started."""
        for axis, motion_id in started_motions(reply).items():
            self.started[axis] = max(self.started.get(axis, 0), motion_id)

    @property
    def moving(self) -> bool:
        """A motion we started has not ended (motion ids rise on each axis; ends come in order)."""
        return any(motion_id > self.ended.get(axis, 0) for axis, motion_id in self.started.items())

    def write(self, data: bytes) -> None:
        now = self.clock.now()
        if now - self.last_write_s >= self.settings.link_timeout_s:
            self.lapsed = True       # the controller heard nothing from us for a whole link timeout
        self.last_write_s = now
        try:
            self.line.write(data)
        except OSError as exc:
            raise TargetGone(f"writing to {self.url}: {exc}", broken=True) from None

    def pump(self, wire_out: bool = True, wait_s: float = 0.0) -> None:
        """One turn: what came in to the host (waiting at most `wait_s` for it), its timers, what it has to send.
        All that is there is read at once: pyserial's socket:// says at most one byte is waiting, so reading by
        what it says took a select and a recv a byte (95 % of the fuzzer's time, profiled)."""
        try:
            if wait_s > 0:
                select.select([self._fd], [], [], wait_s)
            data = self.line.serial.read(READ_SIZE)
        except (OSError, ValueError) as exc:        # ValueError: a descriptor closed under the select
            raise TargetGone(f"reading {self.url}: {exc}", broken=True) from None
        now = self.clock.now()
        if data:
            self.host.feed(data, now)
        self.host.poll(now)
        if wire_out:
            out = self.host.take_all(now)
            if out:
                self.write(out)

    def call(self, msg, timeout_s: float):
        """Send `msg` in sequence and pump until it has an outcome or `timeout_s` passes; its handle (done or not)."""
        handle = self.host.submit(msg, self.clock.now())
        self.pump_until(lambda: handle.done, timeout_s)
        self.learned.learn(handle.reply)
        return handle

    def pump_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Pump until `done()`: False once `timeout_s` is past (`bound`) or the target we started has exited."""
        self._own.begin()
        past = Bound(timeout_s if self.child is not None else self.pace.deadline_s(timeout_s), self._own)
        while not done():
            if self.exited() or past():
                return False
            self.pump(wait_s=READ_WAIT_S)
        return True

    def wait(self, seconds: float, wire_out: bool = True) -> None:
        """Pump for `seconds` of wall time (a step's pause, a silence)."""
        end = _CLOCK.now() + seconds
        while (left := end - _CLOCK.now()) > 0:
            self.pump(wire_out, min(READ_WAIT_S, left))

    def bound(self, timeout_s: float) -> "Bound":
        """`timeout_s` from now: of the target's own time if we started it; else stretched by the target's measured
        pace (`Pace`), and of this process's own time (a fuzzer kept from running has not yet read what the target
        said). (`pump_until` judges by the one own time the session keeps.)"""
        if self.child is not None:
            return Bound(timeout_s, self.child.own_time())
        return Bound(self.pace.deadline_s(timeout_s), OwnTime(os.getpid(), self.clock))

    def exited(self) -> Optional[int]:
        return None if self.child is None else self.child.exit_status()

    def close(self) -> str:
        """Close the line and stop our target; its stderr's last lines."""
        try:
            if self.line is not None:
                self.line.close()
        except OSError:
            pass
        if self.child is None:
            return ""
        _status, err = self.child.stop()
        return "\n".join(err.splitlines()[-12:])


class Pace:
    """How fast a --url target runs, measured at each health check: its rate (its simulated seconds a wall second,
    from its uptime) and its round trip (the check's Ping). A target we did not start is judged on the wall clock,
    so its deadlines stretch by its slowness (at most 1/RATE_FLOOR), at once when it slows down and gradually when
    it speeds up again, and are at least RTT_FACTOR of its recent round trips."""

    def __init__(self) -> None:
        self.slowness = 1.0
        self.rtt_s = 0.0

    def measured(self, rate: float, rtt_s: float) -> None:
        if rate > 0:
            slow = 1.0 / max(RATE_FLOOR, min(1.0, rate))
            self.slowness = max(slow, RATE_KEEP * self.slowness + (1 - RATE_KEEP) * slow)
        self.rtt_s = RATE_KEEP * self.rtt_s + (1 - RATE_KEEP) * rtt_s if self.rtt_s else rtt_s

    def deadline_s(self, timeout_s: float) -> float:
        return max(timeout_s * self.slowness, RTT_FACTOR * self.rtt_s)


class Bound:
    """Called, whether `timeout_s` is past: of the wall clock, and then, if `own` (a target we started) is given, of
    its own time, looked at every `OWN_TIME_LOOK_S`; `last` is the latest look (None: none yet)."""

    def __init__(self, timeout_s: float, own: Optional[OwnTime]) -> None:
        self.timeout_s, self.own = timeout_s, own
        self.end = _CLOCK.now() + timeout_s
        self.last: Optional[Look] = None

    def __call__(self) -> bool:
        if _CLOCK.now() <= self.end:
            return False
        if self.own is None:
            return True
        self.last = self.own.look()
        if out_of_time(self.last, self.timeout_s):
            return True
        self.end = _CLOCK.now() + OWN_TIME_LOOK_S        # kept from running: look again in a while
        return False


class Case:
    """A case's steps, drawn from `draw`, or given (a finding's, replayed)."""

    def __init__(self, steps: list[dict]) -> None:
        self.steps = steps

    @property
    def closes(self) -> bool:
        """A step of it is a Close (sent in sequence, or a frame of ours that may run): the session may end."""
        return any(step.get("msg") == "Close" and step["kind"] in ("command", "burst", "frame") for step in self.steps)

    @property
    def silent(self) -> bool:
        return any(step["kind"] == "silence" for step in self.steps)

    @classmethod
    def draw(cls, draw: RandomDraw, settings: BlackBoxSettings, words: Words = NO_WORDS,
             learned: Boundaries = NO_BOUNDARIES) -> "Case":
        commands = settings.commands
        chain = draw_chain(commands, draw, settings.max_steps) if draw.pick(CHAIN_ONE_IN) == 0 else []
        if chain:        # a sequence, each command sent once the last one's reply says what it must carry
            return cls([{"kind": "command", "delay_s": 0.0, "msg": spec.name, "follow": True,
                         "payload": draw_payload(spec, draw, words, learned, follow=True).hex()} for spec in chain])
        steps = []
        for _ in range(1 + draw.pick(settings.max_steps)):
            kind = "silence" if draw.pick(SILENCE_ONE_IN) == 0 else STEP_KINDS[draw.pick(len(STEP_KINDS))]
            step: dict = {"kind": kind, "delay_s": 0.0 if draw.pick(PAUSE_ONE_IN) else
                          draw.pick(DELAY_MAX_MS + 1) / 1000.0}
            if kind == "command":
                spec = commands[draw.pick(len(commands))]
                step.update(msg=spec.name, payload=draw_payload(spec, draw, words, learned)[:MAX_PAYLOAD].hex())
            elif kind == "frame":
                spec = TO_CONTROLLER[draw.pick(len(TO_CONTROLLER))]
                step.update(msg=spec.name, cls=int(spec.cls) if draw.pick(8) else draw.int_in(0, 255),
                            seq=FRAME_SEQS[draw.pick(len(FRAME_SEQS))], offset=draw.pick(OFFSET_MAX + 1),
                            any_seq=draw.int_in(0, 0xFFFF),
                            payload=draw_payload(spec, draw, words, learned)[:MAX_PAYLOAD].hex(),
                            mac=MACS[4 + draw.pick(len(MACS) - 4)] if draw.pick(2) else "good",
                            version=1 if draw.pick(8) else draw.int_in(0, 255),
                            flags=0x10 if draw.pick(8) else draw.int_in(0, 255),
                            length_delta=0 if draw.pick(8) else draw.int_in(-LENGTH_DELTA, LENGTH_DELTA))
            elif kind == "replay":
                step.update(which=draw.pick(SENT_KEPT))
            elif kind == "raw":
                step.update(bytes=draw.raw(RAW_MAX).hex())
            elif kind == "hello":
                hello = SCHEMA["Hello"]
                values = [draw_value(f, draw) for f in hello.fields]
                step.update(payload=pack_raw(hello, values).hex())
            elif kind == "burst":
                step.update(count=BURST_MIN + draw.pick(BURST_MAX - BURST_MIN + 1))
            elif kind == "silence":
                step.update(fraction=SILENCE_MIN + draw.pick(int((SILENCE_MAX - SILENCE_MIN) * 100) + 1) / 100.0)
            steps.append(step)
        return cls(steps)

    def run(self, session: Session, draw: RandomDraw) -> tuple[list, int]:
        """Send the steps; the handles of the commands sent in sequence, and how many crafted frames may have
        run (authentic urgent ones: that class is taken in any order, so one may land on an unused number)."""
        handles, maybe = [], 0
        for step in self.steps:
            if step["delay_s"]:
                session.wait(step["delay_s"])
            kind = step["kind"]
            repeat = step.get("count", 1) if kind == "burst" else 1
            for _ in range(repeat):
                if kind in ("command", "burst"):
                    spec = SCHEMA[step.get("msg", "Ping")]
                    payload = bytes.fromhex(step.get("payload", "00000000"))
                    if step.get("follow"):
                        payload = self._follow(spec, payload, handles, session, draw)
                        step["payload"] = payload.hex()      # as sent
                    handles.append((spec, payload, session.host.submit_payload(spec, payload, session.clock.now())))
                    if kind == "burst":
                        session.write(session.host.take_all(session.clock.now()))   # all at once, no read between
                        continue
                elif kind == "frame":
                    wire = self._frame(step, session, draw)
                    step["wire"] = wire.hex()          # as sent (a replay re-signs it in its own session)
                    session.write(wire)
                    maybe += step["mac"] == "good" and step["cls"] == MsgClass.URGENT
                elif kind == "replay" and session.sent:
                    session.write(session.sent[step["which"] % len(session.sent)])
                elif kind == "raw":
                    session.write(bytes.fromhex(step["bytes"]))
                elif kind == "hello":
                    from protocol.framing import encode_signed
                    host = session.host
                    host._handshake_tx_counter += 1
                    wire, _tag = encode_signed(MsgClass.LINK, 0, 0xFFFF, SCHEMA["Hello"].id,
                                               bytes.fromhex(step["payload"]), host._handshake.tx,
                                               host._handshake_tx_counter)
                    step["wire"] = wire.hex()
                    session.write(wire)
                elif kind == "silence":      # read and keep, send nothing: not even a heartbeat
                    session.wait(step["fraction"] * session.settings.link_timeout_s, wire_out=False)
                session.pump()
        return handles, maybe

    @staticmethod
    def _follow(spec, payload: bytes, handles: list, session: Session, draw: RandomDraw) -> bytes:
        """`payload` as the replies to the case's commands before it say the next one must carry (waiting for them,
        at most the health deadline: a reply not come is the health check's to judge); a command that carries
        nothing a reply says (TrajClear) goes at once."""
        if not any(f"{spec.name}.{fld.name}" in FOLLOWS for fld in spec.fields):
            return payload
        session.pump_until(lambda: all(h.done for _spec, _payload, h in handles), session.settings.health_timeout_s)
        for _spec, _payload, h in handles:
            session.learned.follow(h.reply)
        return refollow(spec, payload, session.learned, draw)

    @staticmethod
    def _frame(step: dict, session: Session, draw: RandomDraw) -> bytes:
        host = session.host
        spec = SCHEMA[step["msg"]]
        sender = host._commands if step["cls"] == MsgClass.COMMAND else host._urgent
        base = (sender.next_seq - 1) & 0xFFFF
        how = step["seq"]
        if step["cls"] == MsgClass.URGENT and step["mac"] == "good":
            how = "duplicate"     # urgent frames are taken in any order: an authentic one with a sequence number
            #                       the host's sender has not used yet would run, and take that number from it
        seq = {"duplicate": (base - step["offset"]) & 0xFFFF,
               "gap": (sender.next_seq + 1 + step["offset"]) & 0xFFFF}.get(how, step["any_seq"])
        if step["mac"] == "good":
            seq = _unclaimed(seq, sender, step["offset"])
        recipe = FrameRecipe(spec, step["cls"], seq, bytes.fromhex(step["payload"]), step["mac"], step["version"],
                             step["flags"], step["length_delta"])
        wire = build(recipe, host.session, _Peer(session.accepted_counter), host._handshake.tx, host._ack_value(),
                     draw)
        session.sent = (session.sent + [wire])[-SENT_KEPT:]
        return wire


def _unclaimed(seq: int, sender: ReliableSender, offset: int) -> int:
    """`seq` for an authentic frame of ours, unless the host's own frames claim it: one the host sent and has no answer
    to yet, the next it will send, or, in a class taken in any order (urgent), any after. The target would run ours
    under that number and take the host's own for a repeat of it, answering with our command's reply: a finding of
    the fuzzer's own making ("Status in answer to MoveBy", a 150 s run). Such a number becomes one answered already,
    `offset` before the oldest the host still waits on."""
    flying = sender.in_flight_seqs()
    ahead = seq_delta(seq, sender.next_seq)
    if seq in flying or ahead == 0 or (ahead > 0 and not sender.in_order):
        return ((flying[0] if flying else sender.next_seq) - 1 - offset) & 0xFFFF
    return seq


def _whole(lo: int, hi: int) -> Callable[[object], Optional[str]]:
    return lambda v: None if type(v) is int and lo <= v <= hi else f"a whole number {lo}..{hi}"


def _number(lo: float, hi: float) -> Callable[[object], Optional[str]]:
    return lambda v: None if type(v) in (int, float) and lo <= v <= hi else f"a number {lo:g}..{hi:g}"


def _one_of(names) -> Callable[[object], Optional[str]]:
    names = tuple(dict.fromkeys(names))
    said = ", ".join(names) if len(names) <= 10 else ", ".join(names[:8]) + f", ... ({len(names)} names)"
    return lambda v: None if isinstance(v, str) and v in names else f"one of {said}"


def _hex(most: int) -> Callable[[object], Optional[str]]:
    def check(v: object) -> Optional[str]:
        try:
            if isinstance(v, str) and len(v) <= 2 * most and len(bytes.fromhex(v)) <= most:
                return None
        except ValueError:
            pass
        return f"hexadecimal of at most {most} bytes"
    return check


_COMMAND_NAMES = [s.name for s in COMMANDS]
_STEP_FIELDS: dict[str, dict[str, Callable[[object], Optional[str]]]] = {    # what each kind needs
    "command": {"msg": _one_of(_COMMAND_NAMES), "payload": _hex(MAX_PAYLOAD)},
    "frame": {"msg": _one_of(s.name for s in TO_CONTROLLER), "cls": _whole(0, 255), "seq": _one_of(FRAME_SEQS),
              "offset": _whole(0, OFFSET_MAX), "any_seq": _whole(0, 0xFFFF), "payload": _hex(MAX_PAYLOAD),
              "mac": _one_of(MACS), "version": _whole(0, 255), "flags": _whole(0, 255),
              "length_delta": _whole(-LENGTH_DELTA, LENGTH_DELTA)},
    "replay": {"which": _whole(0, SENT_KEPT - 1)},
    "raw": {"bytes": _hex(RAW_MAX)},
    "hello": {"payload": _hex(MAX_PAYLOAD)},
    "burst": {"count": _whole(BURST_MIN, BURST_MAX)},
    "silence": {"fraction": _number(SILENCE_MIN, SILENCE_MAX)},
}
_STEP_OPTIONAL: dict[str, Callable[[object], Optional[str]]] = {
    "seed": _whole(0, (1 << 32) - 1),               # the case's, on its first step
    "wire": _hex(MAX_ENCODED + 2),                  # a frame as it was sent, delimiters included
    "follow": lambda v: None if type(v) is bool else "true or false",    # a command of a sequence (`draw_chain`)
}
_BURST_OPTIONAL = {"msg": _STEP_FIELDS["command"]["msg"], "payload": _STEP_FIELDS["command"]["payload"]}
_COMMON = {"kind": _one_of(_STEP_FIELDS), "delay_s": _number(0, DELAY_MAX_MS / 1000)}


def check_steps(steps: object) -> None:
    """`steps` as the fuzzer writes them: 1..MAX_STEPS objects, each with its kind's fields, each field of its
    type and within the bounds the fuzzer draws it from; ValueError naming the step, the field and what it must
    be (so that a replay neither crashes, nor waits for ever, nor sends without end)."""
    if not isinstance(steps, list) or not 1 <= len(steps) <= MAX_STEPS:
        raise ValueError(f"\"steps\" must be a list of 1..{MAX_STEPS} steps")
    for index, step in enumerate(steps):
        if not isinstance(step, dict):
            raise ValueError(f"step {index} must be an object")
        kind = step.get("kind")
        rules = dict(_COMMON)
        if kind in _STEP_FIELDS:
            rules.update(_STEP_FIELDS[kind])
        for name, rule in rules.items():
            if name not in step:
                raise ValueError(f"step {index} ({kind if kind in _STEP_FIELDS else 'a step'}) has no \"{name}\"; "
                                 f"it must be {rule(None)}")
        if kind == "burst":
            rules.update(_BURST_OPTIONAL)
        rules.update(_STEP_OPTIONAL)
        for name, rule in rules.items():
            if name in step:
                must = rule(step[name])
                if must is not None:
                    raise ValueError(f"step {index}, \"{name}\": {_shown(step[name])}; it must be {must}")


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


class HealthCheck:
    """The target after the cases since the last check: alive, answering, counting right, in the state it should
    be. A case's commands are counted as it ends (`note`); the check (`check`) judges them all together."""

    def __init__(self, session: Session) -> None:
        self.session = session
        self.token = 0
        self._clear()
        self.last = self._status()
        past = session.bound(session.settings.health_timeout_s)
        while self.last.state == ControllerState.BOOT and not past():   # its boot check still running
            self.last = self._status()

    def _clear(self) -> None:
        self.outstanding: list = []   # their commands not yet answered
        self.cases = 0           # cases since the last check
        self.ran = 0             # their commands that must have run (those whose payload decodes, answered)
        self.sent = 0            # their commands sent in sequence
        self.maybe = 0           # what of theirs may have run: authentic urgent frames, commands the host gave up on
        self.accepted = False    # any of their commands (or an authentic urgent frame) accepted
        self.unfinished = False  # a command of theirs had no outcome when its case ended
        self.violation: Optional[str] = None    # the first reply that broke the declaration (host_tools/fuzz/oracles.py)

    def _call(self, msg):
        s = self.session
        return self._reply(s.call(msg, s.settings.health_timeout_s), msg)

    def _reply(self, handle, msg):
        """`handle`'s reply; TargetGone if it has none (not answered, or refused)."""
        s = self.session
        if not handle.done:
            status = s.exited()
            raise TargetGone(f"{msg.spec.name} not answered within {s.settings.health_timeout_s:g} s"
                             + (" of its own time" if s.child is not None else
                                f" (x{s.pace.slowness:.2g} for its measured slowness)" if s.pace.slowness > 1 else "")
                             + (f" (the target exited with status {status})" if status is not None else "")
                             + f"; link {s.host.state.value}")
        if not handle.ok:
            raise TargetGone(f"{msg.spec.name}: {handle.describe()}")
        return handle.reply

    def rebase(self, limits_changed: bool = False) -> Optional[str]:
        """The status now is what the next case is judged against (after commands of the fuzzer's own: the
        parameter table read, a case's parameters set back). What is wrong if the state or faults changed since
        the last check for no cause outside the target (reading or setting back parameters must not), else None.
        `limits_changed`: a case set parameters (now set back), so new faults may be theirs: a supply limit of
        60 V latches SUPPLY_LOW a few ticks after it was set, perhaps after the check that followed the case."""
        before, self.last = self.last, self._status()
        self._clear()
        changed = (self.last.state, self.last.faults) != (before.state, before.faults)
        new = self.last.faults & ~before.faults
        latched = self.last.state == ControllerState.FAULT or self.last.state == before.state == ControllerState.ESTOP
        if changed and not (latched and new and (limits_changed or self._explained(new))):
            return (f"state {before.state}/faults {before.faults:#x} became {self.last.state}/"
                    f"{self.last.faults:#x}")
        return None

    def _status(self, handle=None):
        """The target's status (from `handle`, a GetStatus sent already, if given)."""
        msg = SCHEMA["GetStatus"].type()
        status = self._call(msg) if handle is None else self._reply(handle, msg)
        self.session.accepted_counter = self.session.host.session.tx_counter   # answered: its counter was taken
        self.status_s = _CLOCK.now()
        return status

    def note(self, handles: list, maybe: int = 0) -> bool:
        """Count a case's commands as their replies come: a case does not wait for its own (the next one runs while
        they come, as a host's commands may; `settle` waits for them all). True if every command answered since
        the last `note` was answered as the case expects: none lost with the session, none accepted whose payload
        does not decode."""
        self.outstanding += handles
        self.cases += 1
        self.sent += len(handles)
        self.maybe += maybe
        self.accepted |= maybe > 0
        return self._count()

    def _count(self) -> bool:
        expected, left = True, []
        for spec, payload, h in self.outstanding:
            if not h.done:
                left.append((spec, payload, h))
                continue
            if h.ok and h.reply is not None and h.reply.spec.name == "MotionAccepted":
                self.session.note_started(h.reply)
            self.session.learned.learn(h.reply)
            told = oracles.case_violation([(spec, payload, h)], {})      # each reply against the declaration
            self.violation = self.violation or told
            expected &= told is None
            decodes = _decodes(spec, payload)
            unknown = h.outcome is Outcome.FAILED and decodes     # the host gave up on it: it may have run
            self.accepted |= h.ok or unknown
            self.ran += h.outcome is not Outcome.FAILED and decodes
            self.maybe += unknown
            expected &= not (h.outcome is Outcome.FAILED or (h.ok and not decodes))
        self.outstanding = left
        return expected

    def settle(self) -> None:
        """Wait for the replies to every command counted (at most the health deadline)."""
        s = self.session
        s.pump_until(lambda: all(h.done for _spec, _payload, h in self.outstanding), s.settings.health_timeout_s)
        self._count()
        if self.outstanding:
            self.unfinished, self.outstanding = True, []

    def check(self, handles: Optional[list] = None, maybe: int = 0) -> Optional[str]:
        """None if healthy, else what is wrong (TargetGone if it does not answer); `handles`: a case's commands
        not yet counted (`note`)."""
        if handles is not None:
            self.note(handles, maybe)
        s = self.session
        self.token = (self.token + 1) & 0xFFFFFFFF
        ping = SCHEMA["Ping"].type(token=self.token)
        asked = s.host.submit(ping, s.clock.now())    # both at once, behind the cases' commands: they are taken in
        told = s.host.submit(SCHEMA["GetStatus"].type(), s.clock.now())      # order, so one wait, not three
        s.pump_until(lambda: asked.done and told.done, s.settings.health_timeout_s)
        self.settle()            # (answered before the two, unless lost on the way)
        pong = self._reply(asked, ping)
        rtt_s = asked.latency_s or 0.0
        if pong.token != self.token:
            return f"Pong carries token {pong.token}, the Ping {self.token}"
        since_s = self.status_s
        status = self._status(told)
        before, self.last = self.last, status
        cases, ran, sent, maybe, accepted, unfinished = (self.cases, self.ran, self.sent, self.maybe, self.accepted,
                                                         self.unfinished)
        violation = self.violation
        self._clear()
        if violation is not None:
            return violation
        if s.child is None and self.status_s > since_s:       # a --url target's pace, for its deadlines
            s.pace.measured((status.uptime_ms - before.uptime_ms) / 1000.0 / (self.status_s - since_s), rtt_s)
        if status.uptime_ms < before.uptime_ms and status.uptime_ms > 1000:   # (a wrap after 49 days)
            return f"uptime went back: {before.uptime_ms} ms then {status.uptime_ms} ms"
        #  (the same uptime twice is no fault: two checks' commands answered in one tick of a target held from
        #  running between them, as tests/test_fuzz.py's busy machine did, 2026-11-29)
        told = oracles.state_violation(status.state, status.faults)
        if told is not None:
            return told
        whose = "the case's" if cases <= 1 else f"the {cases} cases'"
        if not unfinished:
            moved = (status.commands_executed - before.commands_executed) & 0xFFFFFFFF
            if not ran + 2 <= moved <= ran + 2 + maybe:        # + the last GetStatus and this Ping
                return (f"commands executed moved by {moved}, expected {ran + 2}" + (f"..{ran + 2 + maybe}" if maybe
                        else "") + f" ({ran} of {whose} {sent} commands decode, + Ping and GetStatus"
                        + (f", + up to {maybe} that may have run: authentic urgent frames, commands the host gave up "
                           f"on" if maybe else "") + "): not exactly once")
        explained = self._explained(status.faults & ~before.faults)
        s.lapsed = False
        s.events = 0
        if not accepted and (status.state, status.faults) != (before.state, before.faults) and not (
                status.state == ControllerState.FAULT and explained):
            return (f"state {before.state}/faults {before.faults:#x} became {status.state}/{status.faults:#x} "
                    f"with no command of {whose} accepted")
        return None

    def _explained(self, new: int) -> bool:
        """True if faults `new` have a cause other than the case: the plant under a motion we started, our own
        silence past the link timeout, or the target saying it is too slow for real time."""
        allowed = Fault.SCHEDULER_OVERRUN
        if self.session.moving:
            allowed |= MOTION_FAULTS
        if self.session.lapsed:
            allowed |= Fault.LINK_LOST
        return bool(new) and not new & ~allowed


class TargetParams:
    """The target's parameter table as the fuzzer found it (ParamList, at the first session).

    Its names are the grammar's words for ParamGet's and ParamSet's `name` (a parameter's name is the controller's,
    not the declaration's: without them no ParamSet reaches a parameter). After each case's health check, every
    parameter a ParamSet of the case may have changed is set back to the value found, so every case starts from
    the configuration the target was found in, as a finding replayed alone on a fresh target does. One that cannot
    be set back yet (BUSY: its joint still moves) is owed, and tried again after every case until it is. A target
    that does not list its parameters is fuzzed without them, and says so on stderr."""

    def __init__(self, table: ParamTable) -> None:
        self.found = {r.name: r.value for r in table.replies}      # as ParamValue carries them (f32)
        self.words: Words = MappingProxyType({"name": table.names}) if table.names else NO_WORDS
        self.put_back = 0                   # parameters set back after a case changed them
        self.owed: set[str] = set()         # changed, not yet set back
        self._said: set[str] = set()        # owed parameters said on stderr (once each)

    @classmethod
    def read(cls, session: Session) -> "TargetParams":
        table = read_param_table(session, session.settings.health_timeout_s)
        if table.failed is not None:
            print(f"aspod fuzz: the target's parameters not read past {len(table.replies)} "
                  f"({table.failed.describe()}); ParamGet and ParamSet draw names from the "
                  f"{len(table.replies)} read and the grammar", file=sys.stderr)
        return cls(table)

    def untouched(self, case: "Case") -> dict[str, float]:
        """The parameters as found that only the case's commands in sequence may have changed: not owed, not named
        by a ParamSet frame the fuzzer crafted (which may run whatever its class)."""
        crafted = {_param_name(bytes.fromhex(step["payload"])) for step in case.steps
                   if step["kind"] == "frame" and step.get("msg") == "ParamSet"}
        return {name: value for name, value in self.found.items() if name not in self.owed and name not in crafted}

    def touched(self, case: "Case", handles: list) -> bool:
        """Whether the case may have changed a parameter (a ParamSet of it accepted or not answered, or one crafted
        and signed), or one is owed from before."""
        return bool(self.owed) or any(spec.name == "ParamSet" and (h.ok or not h.done)
                                      for spec, _payload, h in handles) or any(
            step["kind"] == "frame" and step.get("msg") == "ParamSet" and step["mac"] == "good" for step in case.steps)

    def values_after(self, session: Session, case: "Case", handles: list) -> tuple[dict[str, float], bool]:
        """What each parameter the case may have changed holds now: the last accepted ParamSet's reply says, and
        ParamGet asks where nothing does (a ParamSet not answered, a crafted ParamSet frame, which may run whatever
        its class, a parameter owed from before); and whether it sent any ParamGet."""
        now: dict[str, float] = {}
        unsure = set(self.owed)
        for spec, payload, h in handles:
            if spec.name == "ParamSet" and h.ok:
                now[h.reply.name] = h.reply.value          # the handles are in the order sent: the last one holds
            elif spec.name == "ParamSet" and not h.done:
                unsure.add(_param_name(payload))
        unsure |= {_param_name(bytes.fromhex(step["payload"])) for step in case.steps
                   if step["kind"] == "frame" and step.get("msg") == "ParamSet"}
        asked = sorted(n for n in unsure if n in self.found)
        for name in asked:
            handle = session.call(SCHEMA["ParamGet"].type(name=name), session.settings.health_timeout_s)
            if handle.ok:
                now[name] = handle.reply.value
        return {name: value for name, value in now.items() if name in self.found}, bool(asked)

    def restore(self, session: Session, case: "Case", handles: list) -> bool:
        """Set back what the case changed (in two passes: a limit may be refused until its partner is back);
        True if the fuzzer sent any command of its own here."""
        values, asked = self.values_after(session, case, handles)
        left = {name: None for name, value in values.items() if not _same_f32(value, self.found[name])}
        sent = asked or bool(left)
        self.owed -= {name for name in self.owed if name not in left}
        for _ in range(2):
            tried, left = left, {}
            for name in tried:
                handle = session.call(SCHEMA["ParamSet"].type(name=name, value=self.found[name]),
                                      session.settings.health_timeout_s)
                if handle.ok:
                    self.put_back += 1
                    self.owed.discard(name)
                else:
                    left[name] = handle
        for name, handle in left.items():
            self.owed.add(name)
            if name not in self._said:
                self._said.add(name)
                print(f"aspod fuzz: {name} could not be set back to {self.found[name]:g} after a case changed it "
                      f"({handle.describe()}); tried again after each case", file=sys.stderr)
        return sent


def _param_name(payload: bytes) -> Optional[str]:
    try:
        return SCHEMA["ParamSet"].decode(payload).name
    except Exception:          # noqa: BLE001 (a payload the controller refuses names nothing it set)
        return None


def _same_f32(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def _decodes(spec, payload: bytes) -> bool:
    try:
        spec.decode(payload)
        return True
    except Exception:          # noqa: BLE001 (a payload the controller must refuse)
        return False


def run_case(case: Case, session: Session, health: HealthCheck, seed: int, params: TargetParams,
             check: bool = True) -> Optional[findings_mod.Failure]:
    """Run `case`; then the health check if `check`, or if the target did not behave as the case expects (a
    command of it not answered, lost with the session, or accepted though its payload does not decode; an event
    the target sent; a Close, our own silence, a parameter the case may have changed), and set back the
    parameters it changed. The failure, or None; `health.cases` is 0 after a check."""
    try:
        handles, maybe = case.run(session, RandomDraw(random.Random(seed)))
        expected = health.note(handles, maybe)
        if case.closes:
            health.settle()          # what its Closes did, from their replies: a session to renew
        renew = session.closed or any(spec.name == "Close" and h.outcome is not Outcome.REJECTED
                                      for spec, _payload, h in handles)
        if renew:
            session.renew()          # the case closed the session (or may have: a Close without an answer)
        touched = params.touched(case, handles)
        param_set = any(spec.name == "ParamSet" for spec, _payload, _h in handles)
        problem = None
        if (check or not expected or renew or case.silent or touched or param_set or session.events
                or session.lapsed):
            problem = health.check()         # (it waits for every reply of the cases, its Ping's behind them)
            if problem is None and param_set:   # a refused ParamSet moved nothing (judged once its replies came)
                problem = oracles.case_violation(handles, params.untouched(case))
            if problem is None and touched and params.restore(session, case, handles):
                problem = health.rebase(limits_changed=True)
                if problem is not None:
                    problem = f"while the fuzzer set back the case's parameters: {problem}"
    except TargetGone as exc:
        past = session.bound(EXIT_WAIT_S)
        while session.child is not None and session.exited() is None and not past():
            _CLOCK.sleep(0.01)    # a line that broke: the process may be on its way out
        status = session.exited()
        kind = "crash" if status is not None or (exc.broken and session.child is None) else "hang"
        still = "" if status is not None or past.last is None else f"; it still ran after {past.last.describe()}"
        return findings_mod.Failure(kind, f"TargetGone: {exc}{still}", session.url, "health")
    if problem is not None:
        return findings_mod.Failure("oracle", f"HealthCheck: {problem}", session.url, "health")
    return None


class BlackBoxFuzzer:
    def __init__(self, settings: BlackBoxSettings, psk: Optional[bytes]) -> None:
        """`psk` None: each target started by `command` says its own key (its ASPOD-KEY line)."""
        self.settings, self.psk = settings, psk
        self.params: Optional[TargetParams] = None     # read at the first session
        self.learned = Boundaries()       # what the target's replies said of its limits (host_tools/fuzz/boundaries.py)

    def _open(self) -> tuple[Session, HealthCheck]:
        session = Session(self.settings, self.psk, self.learned)
        try:
            health = HealthCheck(session)
            if self.params is None:
                self.params = TargetParams.read(session)
                health.rebase()     # the ParamLists counted: a case's count starts after them (a state change
                #                     while they were read is the target's own, and becomes the first baseline)
            return session, health
        except BaseException:        # its first status not had: our target is stopped, not left running
            session.close()
            raise

    def run(self, on_case: Callable[[BlackBoxResult], None] = lambda r: None) -> BlackBoxResult:
        result = BlackBoxResult()
        rng = random.Random(self.settings.seed)
        session, health = self._open()
        start = _CLOCK.now()        # after the first session: reading 76 parameters takes 2.6 s at 115200 baud
        pending: list[tuple[Case, int]] = []      # the cases since the last good health check, with their seeds
        known = findings_mod.Known(self.settings.findings)
        try:
            while True:
                more = (self.settings.cases is None or result.cases < self.settings.cases) and (
                    self.settings.seconds is None or _CLOCK.now() - start < self.settings.seconds)
                if more:
                    case_seed = rng.getrandbits(32)
                    case = Case.draw(RandomDraw(random.Random(case_seed)), self.settings, self.params.words,
                                     self.learned)
                    pending.append((case, case_seed))
                    failure = run_case(case, session, health, case_seed, self.params,
                                       check=len(pending) >= self.settings.check_every)
                    result.cases += 1
                    result.steps += len(case.steps)
                elif health.cases:      # the last cases are judged too
                    failure = run_case(Case([]), session, health, 0, self.params)
                else:
                    break
                if health.cases == 0:
                    result.checks += 1
                    if failure is None:
                        pending = []
                if failure is not None:
                    pinning_from = _CLOCK.now()
                    stderr = session.close()
                    if stderr:
                        failure.trace = stderr
                    case, case_seed, failure = self.bisect(pending, failure, session)
                    pending = []
                    finding = findings_mod.Finding("blackbox", failure, steps=_steps_with_seed(case, case_seed),
                                                   url=self.settings.url or " ".join(self.settings.command),
                                                   execs=result.cases)
                    self._keep(finding, known, result)
                    result.pinning_s += _CLOCK.now() - pinning_from
                    pinning_from = _CLOCK.now()
                    if len(result.findings) + len(result.unsaved) == self.settings.max_findings:
                        break
                    if not self.settings.command:
                        break                  # not ours to restart: the target is as the case left it
                    result.restarts += 1
                    session, health = self._open()
                    result.pinning_s += _CLOCK.now() - pinning_from
                result.wall_s, result.params_put_back = _CLOCK.now() - start, self.params.put_back
                on_case(result)
        finally:
            session.close()
        result.wall_s = _CLOCK.now() - start
        return result

    def _keep(self, finding: findings_mod.Finding, known: "findings_mod.Known", result: BlackBoxResult) -> None:
        """Save `finding`, minimized, or count it in the file of its signature if that is known already."""
        if known.count(finding) is not None:          # its bug found before: no minimizing, no second file
            result.repeats += 1
            return
        if self.settings.command:
            finding = self.minimize(finding)
        try:
            path = known.save(finding)
            if str(path) not in result.findings:
                result.findings.append(str(path))
            else:
                result.repeats += 1
        except OSError as exc:     # not lost: it goes to stderr whole, with the reason
            result.unsaved.append(finding.to_json())
            print(f"aspod fuzz: a finding could not be saved in {self.settings.findings} ({exc}); "
                  f"here it is:\n{json.dumps(finding.to_json(), indent=1)}", file=sys.stderr)

    def bisect(self, pending: list[tuple["Case", int]], failure: findings_mod.Failure,
               session: Session) -> tuple["Case", int, findings_mod.Failure]:
        """The case of `pending` (those since the last good health check, judged together) that failed: each run
        again alone with a check after it, in order, on a fresh target (one we started) or on the same one reset
        to its status now (a --url target that still answers); the first that fails, with its failure. If none
        does (or the target cannot be asked again), the last, its failure saying so."""
        pending = [(c, seed) for c, seed in pending if c.steps]
        last, last_seed = pending[-1] if pending else (Case([]), 0)
        if len(pending) <= 1:
            return last, last_seed, failure
        replayed = "on a fresh target" if self.settings.command else "on the same target"
        try:
            if self.settings.command:
                session, health = self._open()
            elif failure.kind == "oracle":
                session = Session(self.settings, self.psk)
                health = HealthCheck(session)
            else:
                raise TargetGone("gone")
        except TargetGone:
            failure.error += (f" (after {len(pending)} cases checked together, not asked again: the target does "
                              f"not answer; saved with the last)")
            return last, last_seed, failure
        try:
            for case, seed in pending:
                again = run_case(Case([dict(step) for step in case.steps]), session, health, seed, self.params)
                if again is not None:
                    stderr = session.close()
                    if stderr:
                        again.trace = stderr
                    return case, seed, again
        finally:
            session.close()
        failure.error += (f" (after {len(pending)} cases checked together; none failed alone when run again one "
                          f"at a time {replayed}: saved with the last)")
        return last, last_seed, failure

    def replay(self, finding: findings_mod.Finding) -> Optional[findings_mod.Failure]:
        """Run a finding's steps on a fresh session: the failure, or None (it no longer fails)."""
        check_steps(finding.steps)         # (a finding from findings.load has been checked)
        seed = finding.steps[0].get("seed", 0)
        try:
            session, health = self._open()
        except TargetGone as exc:
            return findings_mod.Failure("hang", f"TargetGone: {exc}", "", "health")
        try:
            failure = run_case(Case([dict(s) for s in finding.steps]), session, health, seed, self.params)
            if failure is not None:
                stderr = session.close()
                if stderr:
                    failure.trace = stderr
            return failure
        finally:
            session.close()

    def minimize(self, finding: findings_mod.Finding) -> findings_mod.Finding:
        """Fewest steps, then each step's payload and knobs set back to valid or zero values one at a time, while
        it fails with the same signature, each try on a fresh target. `minimized` only if that ran to its end and
        the result, replayed once more, still fails so."""
        deadline = _CLOCK.now() + self.settings.minimize_s
        wanted = findings_mod.signature(finding, with_trigger=False)     # the trigger is what shrinking finds
        cut = []

        def fails(steps: list[dict]) -> bool:
            if _CLOCK.now() > deadline:
                cut.append(True)
                return False
            failure = self.replay(findings_mod.Finding(finding.target, finding.failure, steps=steps))
            return failure is not None and findings_mod.signature(
                findings_mod.Finding(finding.target, failure, steps=steps), with_trigger=False) == wanted

        steps = minimal_steps(finding.steps, fails)
        failure = self.replay(findings_mod.Finding(finding.target, finding.failure, steps=steps)) if not cut else None
        done = failure is not None and findings_mod.signature(
            findings_mod.Finding(finding.target, failure, steps=steps), with_trigger=False) == wanted
        if not done:
            steps = finding.steps if not cut else steps
        return findings_mod.Finding(finding.target, failure if done else finding.failure, steps=steps,
                                    url=finding.url, execs=finding.execs, minimized=done)


def _steps_with_seed(case: Case, seed: int) -> list[dict]:
    steps = [dict(s) for s in case.steps]
    if steps:
        steps[0]["seed"] = seed        # the draw a replayed "frame" step's flipped bit comes from
    return steps
