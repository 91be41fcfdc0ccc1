"""Command -> acknowledgement round trip over a real pty, beside the wire time of its two frames.

For each case an `aspod sim --pty` subprocess is started (the controller and its
plant, paced at the case's baud: 8N1, 10 bits a byte), a `HostClient` connects over
the pty with a fresh temporary key, and Ping commands are sent one after another;
each one's latency is `CommandHandle.latency_s` (submit -> Pong decoded, on the
host's clock). The floor is the wire time of the two frames at that baud: the
authenticated Ping frame and its authenticated Pong reply (counter and tag
included), exact wire lengths built with `encode_frame`. What is left above the
floor is software: the host pump's 1 ms read timeout, the controller's 1 ms comms
period, the scheduler, the codec and the pty.

Other frames share the line: both ends send a Heartbeat every second, and with
telemetry on, a TelemetryStatus frame already on the wire when the Pong is ready
delays it by up to that frame's wire time. The last case (115200 with telemetry at
10 Hz) shows that cost; the others run with telemetry off.
"""
from __future__ import annotations

import math
import secrets
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from firmware_py.uart import BITS_PER_BYTE
from protocol import auth
from protocol.errors import LinkError
from protocol.framing import encode_frame
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.schema import MsgClass
from timebase import RealClock

from bench import retry_on_own_time
from host_tools.worlds.child import Child, ChildError

REPO_ROOT = Path(__file__).resolve().parent.parent
START_TIMEOUT_S = 30.0         # of the sim's own time (Child.line): its ready lines, however busy the machine
CONNECT_TIMEOUT_S = 20.0       # of the sim's own time: handshakes tried again until it has had this much
CALL_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 5.0
GOAL_MARGIN_S = 0.005          # the goal: p99 within wire time + 5 ms


class BenchSetupError(RuntimeError):
    """The simulator could not be started or reached: no figures for this case."""


@dataclass
class Case:
    baud: int
    telemetry_hz: int
    pings: int
    warmup: int
    paced: bool = True      # False: no wire-time emulation, the software floor alone

    @property
    def label(self) -> str:
        if not self.paced:
            return f"{self.baud}, NO pacing (software)"
        return f"{self.baud} baud, telemetry {'off' if not self.telemetry_hz else f'{self.telemetry_hz} Hz'}"


@dataclass
class CaseResult:
    case: Case
    wire_s: float
    ping_bytes: int
    pong_bytes: int
    latencies_s: list[float] = field(default_factory=list)
    duration_s: float = 0.0
    error: str = ""
    sim_stderr: str = ""

    def pct(self, q: float) -> float:
        """The q-quantile by the nearest-rank method (p99 of 300 samples: the 297th; of 60: the largest)."""
        data = sorted(self.latencies_s)
        rank = math.ceil(round(q * len(data), 9))
        return data[min(max(rank, 1), len(data)) - 1]


# ---------------------------------------------------------------- wire time

def frame_lengths(key: bytes) -> tuple[int, int, int, int]:
    """Exact wire bytes of an authenticated Ping, its Pong, a Heartbeat and a TelemetryStatus frame.

    COBS overhead and both delimiters are included (COBS adds exactly one byte to a
    frame shorter than 254 bytes, whatever its content).
    """
    ping, pong, hb, tm = SCHEMA["Ping"], SCHEMA["Pong"], SCHEMA["Heartbeat"], SCHEMA["TelemetryStatus"]
    token, counter = 0x1234_5678, 1_000
    ping_wire = encode_frame(MsgClass.COMMAND, 7, 0, ping.id, ping.encode(ping.type(token=token)),
                             key=key, counter=counter)
    pong_wire = encode_frame(MsgClass.COMMAND, 7, 3, pong.id,
                             pong.encode(pong.type(int(Reason.OK), token, 123_456)), key=key, counter=counter)
    hb_msg = hb.type(*([0] * len(hb.fields)))
    hb_wire = encode_frame(MsgClass.LINK, 0, 0, hb.id, hb.encode(hb_msg), key=key, counter=counter)
    tm_msg = tm.type(*([0] * len(tm.fields)))
    tm_wire = encode_frame(MsgClass.TELEMETRY, 1, 0, tm.id, tm.encode(tm_msg), key=key, counter=counter)
    return len(ping_wire), len(pong_wire), len(hb_wire), len(tm_wire)


def wire_time_s(nbytes: int, baud: int) -> float:
    return nbytes * BITS_PER_BYTE / baud


# ---------------------------------------------------------------- the simulator subprocess

class SimProcess:
    """`aspod sim --pty` as a real subprocess; `url` is its pty. Always stopped by `close()`."""

    def __init__(self, baud: int, telemetry_hz: int, key_path: Path, clock: RealClock, paced: bool = True) -> None:
        self.clock = clock
        self._stderr = tempfile.TemporaryFile()
        self.child = Child(["sim", "--pty", "--baud", str(baud), "--telemetry-hz", str(telemetry_hz),
                            "--key-file", str(key_path)] + ([] if paced else ["--no-pacing"]), stderr=self._stderr)
        self.proc = self.child.proc
        self._buf = b""
        try:
            link = self._line(START_TIMEOUT_S)
            key = self._line(START_TIMEOUT_S)
        except ChildError as exc:
            self.close()
            raise BenchSetupError(f"{exc}; stderr: {self.stderr()!r}") from None
        except BaseException:
            self.close()
            raise
        if not link.startswith("ASPOD-LINK ") or not key.startswith("ASPOD-KEY "):
            self.close()
            raise BenchSetupError(f"unexpected start-up lines {link!r}, {key!r}")
        self.url = link.split(" ", 1)[1]

    def _line(self, timeout_s: float) -> str:
        return self.child.line(timeout_s).strip()

    def stderr(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace").strip()[-2000:]

    def close(self) -> None:
        self.child.stop(timeout_s=STOP_TIMEOUT_S)


def connect(client, child: Child, timeout_s: float) -> None:
    """`client.connect()` to `child`'s link, tried again while the child has had less than `timeout_s` of its own time:
    one handshake gives up after the link's Hello tries (5, a second apart, on the wall clock, as on a real line),
    which a sim kept from its CPU can miss without being dead. A refusal (a wrong key) ends it at once."""
    retry_on_own_time(child, lambda: client.connect(timeout_s=timeout_s), timeout_s,
                      lambda exc: isinstance(exc, LinkError) and exc.reason is Reason.LINK_SUSPENDED)


# ---------------------------------------------------------------- one case

def run_case(case: Case, key: bytes, key_path: Path) -> CaseResult:
    from host_tools.client.live import HostClient   # imports pyserial; only this benchmark needs it

    ping_b, pong_b, _, _ = frame_lengths(key)
    result = CaseResult(case, wire_time_s(ping_b + pong_b, case.baud), ping_b, pong_b)
    clock = RealClock()
    ping = SCHEMA["Ping"].type
    sim: Optional[SimProcess] = None
    client = None
    try:
        sim = SimProcess(case.baud, case.telemetry_hz, key_path, clock, case.paced)
        client = HostClient(sim.url, key, baud=case.baud)
        connect(client, sim.child, CONNECT_TIMEOUT_S)
        started_s = None
        for i in range(case.warmup + case.pings):
            if i == case.warmup:
                started_s = clock.now()
            token = 0x1000_0000 + i
            handle = client.call(ping(token=token), timeout_s=CALL_TIMEOUT_S)
            if not handle.ok or handle.reply is None or handle.reply.token != token:
                raise BenchSetupError(f"ping {i} did not succeed: {handle.describe()}")
            if i >= case.warmup:
                result.latencies_s.append(handle.latency_s)
        result.duration_s = clock.now() - started_s
    except Exception as exc:   # one failed case is reported in its row; the others still run
        result.error = f"{type(exc).__name__}: {exc}"
    finally:
        if client is not None:
            client.close()
        if sim is not None:
            sim.close()
            if result.error:
                result.sim_stderr = sim.stderr()
    return result


def cases(quick: bool) -> list[Case]:
    if quick:
        return [Case(115200, 0, 50, 5), Case(9600, 0, 10, 2), Case(115200, 10, 50, 5),
                Case(115200, 0, 50, 5, paced=False)]
    return [Case(115200, 0, 300, 20), Case(9600, 0, 60, 5), Case(115200, 10, 300, 20),
            Case(115200, 0, 300, 20, paced=False)]


def run(quick: bool = False) -> list[CaseResult]:
    results = []
    with tempfile.TemporaryDirectory(prefix="aspod-bench-") as tmp:
        key_path = Path(tmp) / "bench.key"
        key = secrets.token_bytes(auth.KEY_BYTES)
        auth.write_key(key_path, key)
        for case in cases(quick):
            results.append(run_case(case, key, key_path))
    return results


# ---------------------------------------------------------------- report

def report(results: list[CaseResult]) -> str:
    ping_b, pong_b, hb_b, tm_b = frame_lengths(bytes(auth.KEY_BYTES))
    lines = ["Command -> acknowledgement round trip (Ping -> Pong) over a real pty to `aspod sim` "
             "(8N1 wire time emulated, 10 bits/byte)",
             f"  wire floor = authenticated Ping ({ping_b} B) + Pong ({pong_b} B) = {ping_b + pong_b} B "
             "at the line rate; latencies in ms",
             "",
             f"  {'case':<30}{'n':>5}{'wire':>8}{'p50':>8}{'p99':>8}{'max':>8}{'p50/wire':>9}{'p99/wire':>9}"
             f"{'p99-wire':>9}{'>goal':>6}  goal: p99 <= wire + 5 ms"]
    for r in results:
        if r.error or not r.latencies_s:
            lines.append(f"  {r.case.label:<30}  FAILED: {r.error or 'no samples'}")
            if r.sim_stderr:
                lines.append(f"    sim stderr: {r.sim_stderr}")
            continue
        p50, p99, worst = r.pct(0.50), r.pct(0.99), max(r.latencies_s)
        head = f"  {r.case.label:<30}{len(r.latencies_s):>5}"
        figures = f"{p50 * 1e3:>8.2f}{p99 * 1e3:>8.2f}{worst * 1e3:>8.2f}"
        if not r.case.paced:
            lines.append(f"{head}{'-':>8}{figures}{'-':>9}{'-':>9}{'-':>9}{'-':>6}  reference: no wire time")
            continue
        wire = r.wire_s
        over = sum(1 for x in r.latencies_s if x > wire + GOAL_MARGIN_S)
        met = "met" if p99 <= wire + GOAL_MARGIN_S else "NOT met"
        lines.append(f"{head}{wire * 1e3:>8.2f}{figures}{p50 / wire:>9.2f}{p99 / wire:>9.2f}"
                     f"{(p99 - wire) * 1e3:>9.2f}{over:>6}  {met}")
    lines += ["",
              "  p50/wire, p99/wire: round trip in wire floors (1.00 = nothing but the line). p99-wire: software "
              "and queueing on top. >goal: samples above wire + 5 ms.",
              f"  A frame already on the wire delays a reply by up to its own wire time: a Heartbeat ({hb_b} B) "
              f"takes {wire_time_s(hb_b, 115200) * 1e3:.1f} ms at 115200 and {wire_time_s(hb_b, 9600) * 1e3:.1f} ms "
              f"at 9600, a TelemetryStatus frame ({tm_b} B) {wire_time_s(tm_b, 115200) * 1e3:.1f} ms at 115200.",
              "  Heartbeats go only after 1 s without other frames, so back-to-back pings carry none; the "
              "controller starts no telemetry frame while a request is arriving (held at most 50 ms).",
              "  Pings go one at a time; latency = CommandHandle.latency_s (submit to decoded Pong, host clock). "
              "p99 by nearest rank (of 300 samples the 4th largest; of 60, the largest).",
              "  The NO pacing row runs the same sim with --no-pacing: the software-only round trip "
              "(host pump, pty, controller comms task, codec)."]
    return "\n".join(lines)


def main(quick: bool = False) -> list[CaseResult]:
    results = run(quick)
    print(report(results), flush=True)
    return results
