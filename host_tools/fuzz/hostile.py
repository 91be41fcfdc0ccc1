"""The hostile controller: `aspod fuzz --as-controller`, a controller that attacks the ground tools connecting to it.

It serves a line (`--serve pty|tcp:PORT`, as `aspod conform --host` does) and says it as `aspod sim` does
(`ASPOD-LINK url`, `ASPOD-KEY path`: the key of `--key-file`, or one it makes), so a host is pointed at it as at a
simulator; or it starts the host itself (`--host-cmd`, `{url}` and `{key}` put in), once per session. The handshake
and the session are the protocol's own (`ControllerLink`, with a hook on what it queues, behind a small
`Application`), so the host's counters, sequence numbers and acknowledgements are right and most frames reach its
handlers. Each case is a few steps drawn
from a seeded generator, each wrong in one thing:

    reply      the next reply the host gets, changed: a field from the grammar (host_tools/fuzz/grammar.py), a
               reply of another type, a refusal with any reason, the wrong class or sequence number, none (the
               host resends), late, twice, or a NAK of the command (its own tag, any reason)
    event      an event in sequence, delivered reliably, its payload from the grammar
    telemetry  a telemetry frame, its payload from the grammar
    frame      a frame built by the fuzzer (link_targets.FrameRecipe) with one thing wrong: its MAC (another key,
               the handshake key, a flipped bit, none, a used counter), version, flags, length, id, class or
               sequence number
    nak        a NAK in the session, its fields from the grammar (half of them naming the host's last command)
    hello      a HelloReply or HelloCookie under the handshake key in the middle of the session
    raw        any bytes;   flood   10-200 frames at once;   stall   nothing at all (heartbeats neither) for a while

After each case the host is judged. It fails if it died (killed by a signal, an exit status not among
`exit_ok`, or a Python traceback on its stderr, a thread's included: a listener that raised in a client's pump
thread leaves the process alive and its link dead), if it sent nothing on the link for `hang_s` of its own time
(host_tools/worlds/own_time.py: the wall time less its waits for a CPU, so a busy machine is not taken for a hung
host), or if the user's `--probe` command does not exit 0 within that much of its own time. A finding holds every
step since the host started (the host's state may need them all), shrunk by replaying subsets on fresh hosts.
"""
from __future__ import annotations

import random
import shlex
import subprocess
import sys
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

from protocol.controller_link import ControllerLink
from protocol.framing import MAX_PAYLOAD, Frame
from protocol.link import NAK_ID, PRIO_URGENT, LinkConfig, LinkState, _Outgoing
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.schema import Message, MsgClass
from protocol.states import ControllerState
from timebase import RealClock

from host_tools.fuzz import findings as findings_mod
from host_tools.fuzz.grammar import RandomDraw, draw_payload, draw_valid, pack_raw
from host_tools.fuzz.hostile_cases import SAVED_STEPS, check_steps, draw_case
from host_tools.fuzz.hostile_host import EXIT_OK, Host, signature, with_values
from host_tools.fuzz.link_targets import FrameRecipe, build
from host_tools.worlds.child import describe_exit, out_of_time
from host_tools.worlds.own_time import OwnTime

_CLOCK = RealClock()           # the wall clock (timebase: the one module that reads it)
TARGET = "hostile"             # a finding's target
CASE_WAIT_S = 0.5              # a case's reply steps wait this long for the host's commands, then the case ends
IDLE_WAIT_S = 0.001
LOOK_S = 0.05                  # past its bound of wall time, how often a silent host's own time is looked at


@dataclass(frozen=True)
class HostileSettings:
    serve: str = "pty"                       # pty | tcp:PORT (host_tools/worlds/ports.py open_endpoint)
    host_cmd: tuple[str, ...] = ()           # the host, started per session; {url} and {key} put in its words
    probe: tuple[str, ...] = ()              # a command whose exit status 0 says the host is healthy
    seconds: Optional[float] = 60.0
    cases: Optional[int] = None
    seed: int = 1
    findings: Path = Path("fuzz-findings")
    baud: int = 115200
    hang_s: float = 10.0                     # the host silent (or its probe unanswered) this long of its own time
    exit_ok: tuple[int, ...] = EXIT_OK       # the host's exit statuses that are not a crash
    link_timeout_s: float = LinkConfig().link_timeout_s
    minimize_s: float = 60.0
    max_findings: Optional[int] = None

    def __post_init__(self) -> None:
        if self.seconds is None and self.cases is None:
            raise ValueError("fuzzing as a controller needs --time or --cases")


@dataclass
class HostileResult:
    cases: int = 0
    steps: int = 0
    wall_s: float = 0.0
    sessions: int = 0            # hosts started (or, without --host-cmd, sessions a host opened)
    longest_silence_s: float = 0.0   # the longest a host in session said nothing, of wall time
    repeats: int = 0             # failures like one saved already in this run (`signature`), counted, not saved
    findings: list[str] = field(default_factory=list)
    unsaved: list[dict] = field(default_factory=list)

    @property
    def cases_per_s(self) -> float:
        return self.cases / self.wall_s if self.wall_s > 0 else 0.0

    def figures(self) -> dict:
        """`--json`'s object."""
        return {"cases": self.cases, "steps": self.steps, "wall_s": round(self.wall_s, 2),
                "cases_per_s": round(self.cases_per_s, 2), "sessions": self.sessions,
                "longest_silence_s": round(self.longest_silence_s, 2), "findings": self.findings,
                "repeats": self.repeats, "unsaved": len(self.unsaved)}

    def describe(self) -> str:
        return (f"as a controller: {self.cases} cases ({self.steps} steps) in {self.wall_s:.1f} s, "
                f"{self.cases_per_s:.1f} cases/s, {self.sessions} host sessions, {len(self.findings)} findings"
                + (f" ({self.repeats} more like them, not saved)" if self.repeats else "")
                + (f", {len(self.unsaved)} not saved (on stderr)" if self.unsaved else ""))


# ---- the controller's end ------------------------------------------------------------------------------------

class HostileLink(ControllerLink):
    """The controller's link with a hook on everything it queues: a reply step armed changes the next reply."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.armed: deque[dict] = deque()       # reply steps waiting for a reply
        self.late: list[tuple[float, tuple]] = []
        self.last_command: Optional[Frame] = None
        self.now = 0.0

    def _handle(self, frame: Frame, spec, now: float) -> None:
        if frame.cls in (MsgClass.COMMAND, MsgClass.URGENT):
            self.last_command = frame
        super()._handle(frame, spec, now)

    def _queue(self, prio: int, cls: int, seq: int, msg_id: int, payload: bytes, handshake: bool = False) -> None:
        if not self.armed or cls not in (MsgClass.COMMAND, MsgClass.URGENT) or msg_id not in SCHEMA.reply_ids:
            super()._queue(prio, cls, seq, msg_id, payload, handshake)
            return
        step = self.armed.popleft()
        how = step["how"]
        if how == "fields":               # the reply's own type, one field (or all) from the grammar
            payload = draw_payload(SCHEMA.by_id[msg_id], RandomDraw(random.Random(step["fields"])))
            step["payload"] = payload[:MAX_PAYLOAD].hex()     # for the record: a replay draws it again
        elif how in ("other", "refusal"):
            msg_id = SCHEMA[step["msg"]].id if how == "other" else SCHEMA["Result"].id
            payload = bytes.fromhex(step["payload"])
        elif how == "class":
            cls = step["cls"]
        elif how == "seq":
            seq = {"duplicate": (seq - 1 - step["offset"]) & 0xFFFF,
                   "gap": (seq + 1 + step["offset"]) & 0xFFFF}.get(step["seq"], step["any_seq"])
        elif how == "drop":
            return                        # the host resends; its duplicate is answered from the reply cache
        elif how == "late":
            self.late.append((self.now + step["late_s"], (prio, cls, seq, msg_id, payload)))
            return
        elif how == "twice":
            super()._queue(prio, cls, seq, msg_id, payload)
        elif how == "nak":                # the command refused by a NAK naming it (its own tag), the reply dropped
            command = self.last_command
            nak = pack_raw(SCHEMA["Nak"], [step["reason"], cls, seq, command.msg_id if command else 0,
                                           step["expected"], command.tag[:8] if command else bytes(8)])
            super()._queue(PRIO_URGENT, MsgClass.LINK, 0, NAK_ID, nak)   # any reason: not checked as encode would
            return
        super()._queue(prio, cls, seq, msg_id, payload[:MAX_PAYLOAD])

    def release_late(self, now: float) -> None:
        due = [item for item in self.late if item[0] <= now]
        self.late = [item for item in self.late if item[0] > now]
        for _due, args in due:
            super()._queue(*args)

    def sign_now(self, cls: int, seq: int, msg_id: int, payload: bytes, now: float, handshake: bool = False) -> bytes:
        """A frame signed at once, authentic in its session (or under the handshake key): b"" if no session."""
        return self._sign(_Outgoing(int(cls), seq, msg_id, payload, handshake), now) or b""


class Application:
    """What the controller answers when nothing is wrong: Ping, GetStatus (its commands counted), one harmless
    parameter (`toy_gain`, as conform's played controller has), Close; any other command its declared reply,
    saying OK, its other fields valid and drawn from the grammar (seeded by the command: the same command, the
    same reply); TelemetryStatus at 10 Hz."""

    TELEMETRY_HZ = 10

    def __init__(self, link: HostileLink, clock) -> None:
        self.link, self.clock = link, clock
        self.started_s = clock.now()
        self.gain = 1.0
        self._telemetry_due = 0.0

    def uptime_ms(self) -> int:
        return int((self.clock.now() - self.started_s) * 1000) & 0xFFFFFFFF

    def execute(self, msg: Message, urgent: bool, now: float) -> Message:
        name, ok = msg.spec.name, int(Reason.OK)
        if name == "Ping":
            return SCHEMA["Pong"].type(ok, msg.token, self.uptime_ms())
        if name == "GetStatus":
            return SCHEMA["Status"].type(ok, int(ControllerState.IDLE), 0, 0, self.uptime_ms(), 28.0, 25.0,
                                         (self.link.commands_executed + 1) & 0xFFFFFFFF, self.TELEMETRY_HZ, 0,
                                         1.0, 0.0, 1.0)
        if name in ("ParamList", "ParamGet", "ParamSet"):
            known = msg.index == 0 if name == "ParamList" else msg.name == "toy_gain"
            if name == "ParamSet" and known and 0.0 <= msg.value <= 10.0:
                self.gain = msg.value
            return SCHEMA["ParamValue"].type(ok if known else int(Reason.UNKNOWN_PARAM), "toy_gain" if known else "",
                                             self.gain, 0.0, 10.0, 0, 1, "", "a number that changes nothing")
        if name == "Close":
            self.link.close_session()
            return SCHEMA["Closed"].type(ok, int(ControllerState.IDLE), 0, self.link.last_event_seq,
                                         int(self.link.config.link_timeout_s * 1000))
        reply = SCHEMA[msg.spec.reply]
        draw = RandomDraw(random.Random(msg.spec.id))
        for _ in range(8):
            payload = pack_raw(reply, [ok if f.name == "result" else draw_valid(f, draw) for f in reply.fields])
            try:
                return reply.decode(payload)
            except Exception:        # noqa: BLE001 (a field with no declared rule drawn broken: draw again)
                continue
        return SCHEMA["Result"].type(int(Reason.NOT_ALLOWED_IN_STATE))

    def telemetry(self, now: float) -> None:
        link = self.link
        if link.quiet or link.session is None or now < self._telemetry_due:
            return
        self._telemetry_due = max(self._telemetry_due + 1.0 / self.TELEMETRY_HZ, now - 0.5)
        link.send_telemetry(SCHEMA["TelemetryStatus"].type(
            self.uptime_ms(), int(ControllerState.IDLE), 0, 0, 28.0, 25.0, link.commands_executed & 0xFFFFFFFF,
            0, 0, 0, 0, 0, 0, 0, 0, 1.0, 0.0))


def write_all(port, data: bytes, clock, bound_s: float = 2.0) -> None:
    """Write all of `data` (a port may take part of it), giving up after `bound_s` (nobody reads: the bytes are
    gone, as on a real line)."""
    until = clock.now() + bound_s
    while data and clock.now() < until:
        data = data[port.write(data):]
        if data:
            clock.sleep(IDLE_WAIT_S)


class _Peer:
    """What the fuzzer knows of the host's counter: the last one it signed (the host took it, or will)."""

    def __init__(self, counter: int) -> None:
        self.rx_counter = counter


# ---- the fuzzer ----------------------------------------------------------------------------------------------

class HostileController:
    """One served line, the controller on it, and the host under test (started per session if `host_cmd`)."""

    def __init__(self, settings: HostileSettings, psk: bytes, key_path: Path, port) -> None:
        self.settings, self.psk, self.key_path, self.port = settings, psk, key_path, port
        self.clock = RealClock()
        self.host: Optional[Host] = None
        self.sessions = 0
        self.longest_silence_s = 0.0     # of wall time, of a host in session: what a wall clock would have judged
        self._new_controller()

    def _new_controller(self) -> None:
        """A controller afresh (a replay, a shrinking try: nothing of an earlier host's sessions left in it)."""
        self.link = HostileLink(self.psk, lambda msg, urgent, now: self.app.execute(msg, urgent, now),
                                LinkConfig(link_timeout_s=self.settings.link_timeout_s))
        self.app = Application(self.link, self.clock)
        if hasattr(self.port, "live_session"):          # a TCP server: it admits by what a client proves
            self.port.live_session = lambda: self.link.session if not self.link.link_lost else None
            self.port.vouch = self.link.vouch
        self.heard_s = self.clock.now()
        self._silence: Optional[tuple[float, Optional[str]]] = None    # the latest look at a silence: (when, verdict)
        self._session_nonce: Optional[bytes] = None

    # the line
    def turn(self, write: bool = True) -> None:
        """Read, feed, timers, telemetry, and (unless `write` is False: a stall) write what the link queued."""
        data = self.port.read(4096)
        now = self.clock.now()
        self.link.now = now
        if data:
            if self.link.state is LinkState.UP and (self.host is None or self.host.in_session):
                self.longest_silence_s = max(self.longest_silence_s, now - self.heard_s)
            self.heard_s, self._silence = now, None
            if self.host is not None:
                self.host.heard()
            self.link.feed(data, now)
        self.link.poll(now)
        self.link.release_late(now)
        if write:
            self.app.telemetry(now)
            while (wire := self.link.take_frame(now)) is not None:
                write_all(self.port, wire, self.clock)
        if self.link.session is not None and self.link.session.host_nonce != self._session_nonce:
            self._session_nonce = self.link.session.host_nonce      # a host adopted a new session
            if self.host is None:
                self.sessions += 1
            else:
                self.host.in_session = True
        if not data:
            self.clock.sleep(IDLE_WAIT_S)

    def write(self, data: bytes) -> None:
        if data:
            write_all(self.port, data, self.clock)

    # the host
    def start_host(self) -> None:
        if self.host is not None or not self.settings.host_cmd:
            return
        argv = with_values(self.settings.host_cmd, self.port.url, str(self.key_path))
        try:
            self.host = Host(argv)
        except OSError as exc:
            raise ValueError(f"--host-cmd {' '.join(argv)}: {exc}") from None
        self.sessions += 1
        self.heard_s, self._silence = self.clock.now(), None

    def stop_host(self) -> str:
        """Stop the host (if it runs); its stderr's last lines."""
        host, self.host = self.host, None
        if host is None:
            return ""
        host.stop()
        return host.stderr()

    def in_session(self) -> bool:
        """A host is in session with the fuzzer: ours has opened one, or (without --host-cmd) some host has one."""
        link = self.link
        up = link.session is not None and link.state is LinkState.UP and not link.link_lost
        return up and (self.host.in_session if self.host is not None else not self.settings.host_cmd)

    def await_session(self) -> tuple[bool, Optional[findings_mod.Failure]]:
        """Until a host is in session (ours started first, if `host_cmd`): (True, None); or it could not be: (False,
        the failure, if the host died or went silent, else None). Ours has `hang_s` of its own time to get there;
        without `host_cmd`, a wait of `CASE_WAIT_S` (a host the user starts comes when it comes)."""
        self.start_host()
        end = self.clock.now() + CASE_WAIT_S
        while not self.in_session():
            if self.host is None and self.clock.now() > end:
                return False, None
            if self.host is not None:
                if self.host.traceback or self.host.status() is not None:
                    return False, self.judge()
                silent = self.silence()
                if silent is not None:
                    return False, self._failure("hang", silent)
            self.turn()
        return True, None

    def judge(self) -> Optional[findings_mod.Failure]:
        """The host now: alive (or ended well), speaking, answering the probe; the failure, or None."""
        host = self.host
        if host is not None:
            status = host.status()
            if host.traceback:
                return self._failure("crash", "a traceback on the host's stderr"
                                     + (f" (it {describe_exit(status)})" if status is not None else
                                        " (it still runs)"))
            if status is not None:
                if status < 0 or status not in self.settings.exit_ok:
                    return self._failure("crash", f"the host {describe_exit(status)}")
                self.host = None          # it ended well (its script done, its link given up): the next starts
                host.stop()
                return None
        silent = self.silence()
        if silent is not None:
            return self._failure("hang", silent)
        if self.settings.probe:
            return self.run_probe()
        return None

    def silence(self) -> Optional[str]:
        """What is wrong if the host has said nothing on the link for `hang_s` of its own time, else None."""
        hang_s = self.settings.hang_s
        if self.clock.now() - self.heard_s <= hang_s:
            return None
        if self.host is None:
            if self.settings.host_cmd or self.link.session is None or self.link.state is not LinkState.UP:
                return None          # no host of ours, and none in session: nobody to wait for
            return f"the host sent nothing for {self.clock.now() - self.heard_s:.1f} s (of wall time: not ours)"
        if self._silence is None or self.clock.now() - self._silence[0] >= LOOK_S:     # (/proc read at most so often)
            look = self.host.own.look()
            self._silence = (self.clock.now(), f"the host sent nothing on the link for {look.describe()}, past "
                                               f"{hang_s:g} s" if out_of_time(look, hang_s) else None)
        return self._silence[1]

    def run_probe(self) -> Optional[findings_mod.Failure]:
        from host_tools.worlds.child import run
        argv = with_values(self.settings.probe, self.port.url, str(self.key_path))
        try:
            done = run(argv, timeout_s=self.settings.hang_s,
                       peers=(self.host.proc.pid,) if self.host is not None else ())
        except subprocess.TimeoutExpired:
            return self._failure("hang", f"the probe `{shlex.join(argv)}` did not end within "
                                         f"{self.settings.hang_s:g} s of its own time")
        except OSError as exc:
            raise ValueError(f"--probe {shlex.join(argv)}: {exc}") from None
        if done.returncode != 0:
            said = (done.stderr or b"").decode(errors="replace").strip().splitlines()[-3:]
            return self._failure("oracle", f"the probe `{shlex.join(argv)}` ended: {describe_exit(done.returncode)}"
                                 + (f" ({' / '.join(said)})" if said else ""), oracle="probe")
        return None

    def _failure(self, kind: str, error: str, oracle: str = "") -> findings_mod.Failure:
        return findings_mod.Failure(kind, error, "host", oracle or kind)

    # a case
    def run_case(self, steps: list[dict]) -> Optional[findings_mod.Failure]:
        """Send `steps` (their reply steps armed for the host's next replies), wait for those to be used (at most
        `CASE_WAIT_S`), then judge the host."""
        ready, failure = self.await_session()
        if not ready:
            return failure
        draw = RandomDraw(random.Random(steps[0]["case"] if steps else 0))   # a flipped bit's (a replay's too)
        for step in steps:
            if step["delay_s"]:
                self._pump_for(step["delay_s"])
            self.do(step, draw)
            self.turn()
            failure = self._ended_badly()
            if failure is not None:
                return failure
        end = self.clock.now() + CASE_WAIT_S
        while self.link.armed and self.clock.now() < end:
            self.turn()
            if self.host is not None and self.host.status() is not None:
                break
        self.link.armed.clear()             # not used in time: a case's steps do not leak into the next
        return self.judge()

    def watch(self, own_s: float) -> Optional[findings_mod.Failure]:
        """After a replay's last case: the host watched until it has had `own_s` of its own time (it may die, or go
        silent, a while after what did it), then judged; the failure, or None."""
        if self.host is None:
            return self.judge()
        own = OwnTime(self.host.proc.pid, RealClock(), tree=True)
        look_s = self.clock.now()
        while self.host is not None and self.host.status() is None and not self.host.traceback:
            self.turn()
            if self.clock.now() - look_s >= 0.1:
                look_s = self.clock.now()
                if self.silence() is not None or out_of_time(own.look(), own_s):
                    break
        return self.judge()

    def _ended_badly(self) -> Optional[findings_mod.Failure]:
        host = self.host
        if host is not None and (host.traceback or host.status() is not None):
            return self.judge()
        return None

    def _pump_for(self, seconds: float, write: bool = True) -> None:
        end = self.clock.now() + seconds
        while self.clock.now() < end:
            self.turn(write)
            if self.host is not None and (self.host.status() is not None or self.host.traceback):
                return

    def do(self, step: dict, draw: RandomDraw) -> None:
        link, now, kind = self.link, self.clock.now(), step["kind"]
        if kind == "reply":
            link.armed.append(step)
        elif kind == "event":
            if link.session is not None and link.state is LinkState.UP:
                link._events.submit(SCHEMA[step["msg"]].id, bytes.fromhex(step["payload"]))
                link.on_work()
        elif kind == "telemetry":
            link._telemetry_seq = (link._telemetry_seq + 1) & 0xFFFF
            self._sent(step, link.sign_now(MsgClass.TELEMETRY, link._telemetry_seq, SCHEMA[step["msg"]].id,
                                           bytes.fromhex(step["payload"]), now))
        elif kind == "frame":
            self._sent(step, self._frame(step, draw))
        elif kind == "nak":
            payload = bytearray(bytes.fromhex(step["payload"]))
            command = link.last_command
            if step["names_command"] and command is not None and len(payload) == SCHEMA["Nak"].size:
                payload[1:6] = bytes([command.cls & 0xFF]) + command.seq.to_bytes(2, "little") + \
                    command.msg_id.to_bytes(2, "little")
                payload[-8:] = command.tag[:8].ljust(8, b"\x00")
            self._sent(step, link.sign_now(MsgClass.LINK, 0, NAK_ID, bytes(payload), now))
        elif kind == "hello":
            payload = bytearray(bytes.fromhex(step["payload"]))
            session = link.session
            if step["same_nonce"] and session is not None and len(payload) >= 16:
                at = 0 if step["msg"] == "HelloCookie" else 10      # after result, version, schema hash
                payload[at:at + 16] = session.host_nonce
            self._sent(step, link.sign_now(MsgClass.LINK, 0, SCHEMA[step["msg"]].id, bytes(payload), now,
                                           handshake=True))
        elif kind == "raw":
            self.write(bytes.fromhex(step["bytes"]))
        elif kind == "flood":
            spec = SCHEMA[step["msg"]]
            payload = bytes.fromhex(step["payload"])
            frames = []
            for _ in range(step["count"]):
                seq = 0
                if spec.cls == MsgClass.TELEMETRY:
                    link._telemetry_seq = (link._telemetry_seq + 1) & 0xFFFF
                    seq = link._telemetry_seq
                frames.append(link.sign_now(spec.cls, seq, spec.id, payload, now))
            self.write(b"".join(frames))
        elif kind == "stall":
            self._pump_for(step["seconds"], write=False)

    def _sent(self, step: dict, wire: bytes) -> None:
        if wire:
            step["wire"] = wire.hex()        # as sent (a replay signs it anew in its own session)
            self.write(wire)

    def _frame(self, step: dict, draw: RandomDraw) -> bytes:
        link = self.link
        if link.session is None:
            return b""
        spec = SCHEMA[step["msg"]]
        recipe = FrameRecipe(spec, int(spec.cls), 0, bytes.fromhex(step["payload"]))
        wrong = step["wrong"]
        if spec.cls == MsgClass.EVENT:
            recipe.seq = link._events.next_seq      # the next in sequence, unless that is what is wrong
        if wrong == "mac":
            recipe.mac = step["mac"]
        elif wrong == "version":
            recipe.version = step["value"] if step["value"] != 1 else 0
        elif wrong == "flags":
            recipe.flags = step["value"] | 0x20
        elif wrong == "length":
            recipe.length_delta = step["length_delta"]
        elif wrong == "msg_id":
            recipe.msg_id = step["msg_id"]
        elif wrong == "cls":
            recipe.cls = step["value"] if step["value"] != int(spec.cls) else (step["value"] + 1) & 0xFF
        elif wrong == "seq":
            recipe.seq = step["seq"]
        return build(recipe, link.session, _Peer(link.session.tx_counter), link._handshake.tx, link._ack_value(),
                     draw)

    def close(self) -> None:
        self.stop_host()


class HostileFuzzer:
    """Cases against the host until `seconds` or `cases`; findings saved (and shrunk, when the fuzzer starts the
    host) as findings are (host_tools/fuzz/findings.py)."""

    def __init__(self, settings: HostileSettings, psk: bytes, key_path: Path, port) -> None:
        self.settings = settings
        self.controller = HostileController(settings, psk, key_path, port)
        self.seen: set[tuple] = set()         # the signatures of the findings saved in this run

    def run(self, on_case: Callable[[HostileResult], None] = lambda r: None) -> HostileResult:
        settings, controller, result = self.settings, self.controller, HostileResult()
        rng = random.Random(settings.seed)
        start = _CLOCK.now()
        steps: list[dict] = []             # since the host started: a finding's input
        try:
            while (settings.cases is None or result.cases < settings.cases) and (
                    settings.seconds is None or _CLOCK.now() - start < settings.seconds):
                if not settings.host_cmd and not controller.in_session():
                    controller.await_session()      # a host the user starts: no case counted until one comes
                    continue
                if controller.host is None:
                    steps = []
                case = draw_case(RandomDraw(random.Random(rng.getrandbits(32))), result.cases)
                steps = (steps + case)[-SAVED_STEPS:]
                failure = controller.run_case(case)
                result.cases += 1
                result.steps += len(case)
                if failure is not None:
                    self._found(failure, steps, result)
                    steps = []
                    if len(result.findings) + len(result.unsaved) == settings.max_findings:
                        break
                result.wall_s, result.sessions = _CLOCK.now() - start, controller.sessions
                result.longest_silence_s = controller.longest_silence_s
                on_case(result)
        finally:
            controller.close()
        result.wall_s, result.sessions = _CLOCK.now() - start, controller.sessions
        return result

    def _found(self, failure: findings_mod.Failure, steps: list[dict], result: HostileResult) -> None:
        """Save a finding, shrunk; one already saved in this run (the same `signature`) is counted, not saved."""
        import json
        stderr = self.controller.stop_host()
        failure.trace = failure.trace or stderr
        said = signature(failure)
        if said in self.seen:
            result.repeats += 1
            return
        self.seen.add(said)
        finding = findings_mod.Finding(TARGET, failure, steps=[dict(s) for s in steps],
                                       url=" ".join(self.settings.host_cmd) or self.controller.port.url,
                                       execs=result.cases)
        if self.settings.host_cmd:
            finding = self.minimize(finding)
        try:
            result.findings.append(str(finding.save(self.settings.findings)))
        except OSError as exc:             # not lost: it goes to stderr whole, with the reason
            result.unsaved.append(finding.to_json())
            print(f"aspod fuzz: a finding could not be saved in {self.settings.findings} ({exc}); here it is:\n"
                  f"{json.dumps(finding.to_json(), indent=1)}", file=sys.stderr)

    def replay(self, steps: list[dict], kind: str = "hang") -> Optional[findings_mod.Failure]:
        """`steps` (a finding's: cases in order) against a fresh controller and a fresh host; the failure, or None.
        Past the last case the host is watched a while more, of its own time: it may die a little after what did
        it (`CASE_WAIT_S`), and a hang (`kind`) takes `hang_s` to show."""
        check_steps(steps)
        controller = self.controller
        controller.stop_host()
        controller._new_controller()
        try:
            cases: dict[int, list[dict]] = {}
            for step in steps:
                cases.setdefault(step["case"], []).append(dict(step))
            for case in cases.values():
                failure = controller.run_case(case)
                if failure is not None:
                    return failure
            return controller.watch(CASE_WAIT_S + (self.settings.hang_s if kind == "hang" else 0.0))
        finally:
            controller.stop_host()

    def minimize(self, finding: findings_mod.Finding) -> findings_mod.Finding:
        """Fewer steps that fail the same way (the same kind), each try on a fresh controller and host."""
        deadline, kind = _CLOCK.now() + self.settings.minimize_s, finding.failure.kind

        def fails(steps: list[dict]) -> bool:
            return _CLOCK.now() <= deadline and getattr(self.replay(steps, kind), "kind", None) == kind

        sessions = self.controller.sessions         # the tries' hosts are not the run's sessions
        steps = findings_mod._ddmin(list(finding.steps), fails)
        while len(steps) > 1 and fails(steps[:-1]):  # the last step is kept by ddmin; here the failing one may
            steps = steps[:-1]                         # be earlier (a host dies a little after what killed it)
        self.controller.sessions = sessions
        if len(steps) == len(finding.steps):
            return finding
        return findings_mod.Finding(finding.target, finding.failure, steps=steps, url=finding.url,
                                    execs=finding.execs, minimized=True)


# ---- the line and the key, as `aspod sim` says them ---------------------------------------------------------------

class Served:
    """The served line and the key (`key_file`, or a new one in this user's runtime folder, removed at `close`),
    said on stdout as `aspod sim` says them: `ASPOD-LINK url`, then `ASPOD-KEY path`."""

    def __init__(self, settings: HostileSettings, key_file: Optional[Path]) -> None:
        from protocol import auth
        from host_tools.worlds.ports import open_endpoint
        from host_tools.worlds.runtime_folder import RuntimeFolder
        self.folder = None
        if key_file is not None:
            self.psk, self.key_path = auth.load_key(key_file, "--key-file"), key_file.absolute()
        else:
            self.folder = RuntimeFolder.open()
            self.psk, self.key_path = self.folder.new_key()
        try:
            self.port = open_endpoint(settings.serve, settings.baud)
        except BaseException:
            self.close()
            raise
        print(f"ASPOD-LINK {self.port.url}", flush=True)
        print(f"ASPOD-KEY {self.key_path}", flush=True)

    def close(self) -> None:
        if getattr(self, "port", None) is not None:
            self.port.close()
        if self.folder is not None:
            self.folder.close()


def fuzz_as_controller(settings: HostileSettings, key_file: Optional[Path],
                       on_case: Callable[[HostileResult], None] = lambda r: None) -> HostileResult:
    served = Served(settings, key_file)
    try:
        return HostileFuzzer(settings, served.psk, served.key_path, served.port).run(on_case)
    finally:
        served.close()


def replay_as_controller(settings: HostileSettings, key_file: Optional[Path],
                         finding: findings_mod.Finding) -> Optional[findings_mod.Failure]:
    served = Served(settings, key_file)
    try:
        return HostileFuzzer(settings, served.psk, served.key_path, served.port).replay(finding.steps,
                                                                                          finding.failure.kind)
    finally:
        served.close()
