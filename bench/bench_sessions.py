"""Sessions: the proxy's cost, the capture decoder's speed beside tshark's, and two links through outages.

1. **Proxy overhead.** Ping round trips from a `HostClient` to `aspod sim --pty` at 115200 baud, directly and
   through `aspod proxy` (impairment `clean`), in the same run: the added latency at p50 and p99 per round
   trip (two frames, one each way). Then the most frames per second the proxy forwards: a writer floods
   the host side of a proxy between two ptys with 40-byte frames, unpaced, and a reader counts what comes
   out of the other side, beside the same flood over a bare pty pair.
2. **Decoding a capture.** A capture of a lock-step session (telemetry at 50 Hz, pings) decoded by
   `aspod log` (a subprocess, its start-up included) and in process (`SessionDecoder`), beside `tshark` with
   the generated dissector on the same file (`-T fields -e aspod.message`), when tshark is installed.
3. **Memory against a capture's size.** Crafted captures of 16 MiB and 250 MiB (`--quick`: 16 MiB only): a
   lock-step session's frames again and again, read by `aspod log` (the listing, `--stats`, `--plot`); and a
   lock-step session followed by dense telemetry (a TelemetryStatus and a TelemetryJoints every millisecond, ten
   times the most a controller sends) of 4, 16 and 64 MiB (`--quick`: 4 and 16), re-simulated by `aspod replay`. Each command in a child
   process whose peak resident set (VmHWM) it reports, beside the same command on a small capture, and its time.
4. **Two links through outages.** `aspod sim --link radio=pty --link optical=tcp:0`, an `aspod proxy` on each:
   the radio fades for 30 s, later the optical link is blocked for 10 s (quick: 4 s and 2 s). A host on both
   sends pings one after another throughout: commands lost (goal 0), executed twice (goal 0: the
   controller's own count against the host's), and the round trip outside the outages and during each. With
   every frame on both links there is no switch-over: the "failover time" is what an outage adds to a round
   trip, shown as the p50 and p99 during it beside the p50 outside.
"""
from __future__ import annotations

import os
import re
import shutil
import statistics
import subprocess
import sys
import threading
from pathlib import Path
from typing import Optional

import serial

from protocol import auth
from protocol.framing import encode_signed
from protocol.messages import MESSAGES as M, SCHEMA
from protocol.schema import MsgClass
from bench import PartsResult, run_parts
from timebase import RealClock
from host_tools.client.lines import parse_links
from host_tools.client.live import HostClient
from host_tools.sessions.capture import DIRECTION_FLAG, CaptureWriter, SessionCapture, SessionInfo
from host_tools.sessions.decode import SessionDecoder
from host_tools.sessions.pcapng import INBOUND, PcapngWriter
from host_tools.sessions.wireshark import generate_dissector
from host_tools.worlds.child import Child
from host_tools.worlds.world import LockstepBench

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
MIB = 1 << 20
# A command in a child that says its peak resident set (VmHWM, KiB: since its exec; ru_maxrss would carry in the
# parent's size at the fork) on its last line of stderr.
MEASURED = ("import re, sys\n"
            "from host_tools.cli.main import main\n"
            "status = main(sys.argv[1:])\n"
            "print('peak_rss_kib', re.search(r'VmHWM:\\s*(\\d+) kB', open('/proc/self/status').read()).group(1), "
            "file=sys.stderr)\n"
            "sys.exit(status)\n")


def pct(samples: list[float], q: float) -> float:
    ordered = sorted(samples)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


class _Env:
    """A private config folder for the children of one benchmark, and the key its simulator made."""

    def __init__(self, folder: Path) -> None:
        self.env = {**os.environ, "XDG_CONFIG_HOME": str(folder / "config")}
        self.children: list[Child] = []
        self.key_path: Optional[Path] = None

    def start(self, args: list[str]) -> tuple[Child, str]:
        child = Child(args, env=self.env)
        self.children.append(child)
        line = child.ready("ASPOD-LINK ", 30.0)
        if args[0] == "sim":
            self.key_path = Path(child.ready("ASPOD-KEY ").split(" ", 1)[1])
        return child, line.split(" ", 1)[1]

    def key(self) -> bytes:
        return auth.load_key(self.key_path)

    def close(self) -> None:
        for child in self.children:
            child.stop(timeout_s=5)
        self.children.clear()


def _pings(url: str, key: bytes, count: int) -> list[float]:
    client = HostClient(url, key)
    try:
        client.connect(20)
        for i in range(20):
            client.call(M["Ping"](i))
        return [client.call(M["Ping"](i)).latency_s for i in range(count)]
    finally:
        client.close()


def proxy_overhead(folder: Path, quick: bool) -> list[str]:
    env = _Env(folder)
    try:
        _, sim_url = env.start(["sim", "--pty", "--no-tracker", "--telemetry-hz", "0"])
        key = env.key()
        count = 100 if quick else 400
        direct = _pings(sim_url, key, count)
        _, proxy_url = env.start(["proxy", "--controller", sim_url, "--no-view"])
        proxied = _pings(proxy_url, key, count)
    finally:
        env.close()
    lines = ["proxy overhead (Ping round trip at 115200 baud, two frames, one each way):"]
    for label, samples in (("direct to aspod sim", direct), ("through aspod proxy", proxied)):
        lines.append(f"  {label:<22} p50 {pct(samples, 0.5) * 1e3:6.2f} ms  p99 {pct(samples, 0.99) * 1e3:6.2f} ms"
                     f"  (n={len(samples)})")
    lines.append(f"  added by the proxy:    p50 {(pct(proxied, 0.5) - pct(direct, 0.5)) * 1e3:+6.2f} ms  "
                 f"p99 {(pct(proxied, 0.99) - pct(direct, 0.99)) * 1e3:+6.2f} ms per round trip")
    return lines + _throughput(folder, quick)


FLOOD_FRAME = b"\x00" + b"\x01" * 38 + b"\x00"     # 40 bytes between and with its delimiters


def _flood(write, read, seconds: float) -> float:
    """Frames per second carried from `write(bytes)` to `read() -> bytes`, 40-byte frames written as fast as the
    writer takes them for `seconds`."""
    received = [0]
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            received[0] += read().count(b"\x00")
    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    clock = RealClock()
    start = clock.now()
    burst = FLOOD_FRAME * 50
    while clock.now() - start < seconds:
        write(burst)
    elapsed = clock.now() - start
    stop.set()
    thread.join(2)
    return received[0] / 2 / elapsed


def _throughput(folder: Path, quick: bool) -> list[str]:
    import select
    import tty
    seconds = 2.0 if quick else 5.0
    master, slave = os.openpty()
    tty.setraw(slave)

    def read_master() -> bytes:
        ready, _, _ = select.select([master], [], [], 0.05)
        return os.read(master, 65536) if ready else b""

    def write_slave(data: bytes) -> None:
        select.select([], [slave], [], 1.0)
        try:
            os.write(slave, data)
        except BlockingIOError:
            pass
    try:
        os.set_blocking(slave, False)
        bare = _flood(write_slave, read_master, seconds)
    finally:
        os.close(master)
        os.close(slave)
    env = _Env(folder)
    try:
        proxy, host_url = env.start(["proxy", "--host", "pty", "--controller", "pty", "--no-view"])
        writer = serial.serial_for_url(host_url, timeout=0, write_timeout=1.0)
        reader = serial.serial_for_url(_controller_pty(proxy), timeout=0.05)

        def write(data: bytes) -> None:
            try:
                writer.write(data)
            except serial.SerialTimeoutException:
                pass
        try:
            through = _flood(write, lambda: reader.read(65536), seconds)
        finally:
            writer.close()
            reader.close()
    finally:
        env.close()
    return [f"  most frames forwarded: {through:,.0f} frames/s through the proxy (40 B each, unpaced, pty to pty), "
            f"beside {bare:,.0f} frames/s over a bare pty pair ({through / bare:.2f}x)"]


def _controller_pty(proxy: Child) -> str:
    found = proxy.wait_stderr(r"<-> (\S+) \(controller\)", 30.0)
    return found.group(1)


def decode_speed(folder: Path, quick: bool) -> list[str]:
    capture = folder / "decode.pcapng"
    bench = LockstepBench(seed=3)
    bench.record(CaptureWriter.create(capture, SessionInfo(clock="simulated", tool="bench", seed=3,
                                                           settings=bench.settings())))
    bench.connect()
    bench.call(M["SetTelemetryRate"](30))
    seconds = 20 if quick else 60
    for i in range(seconds):
        bench.call(M["Ping"](i))
        bench.run_for(1.0)
    bench.close()
    clock = RealClock()
    start = clock.now()
    frames = 0
    with SessionCapture.open(capture) as recorded:
        decoder = SessionDecoder(None)
        for f in recorded.frames():
            decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length)
            frames += 1
    in_process = clock.now() - start
    start = clock.now()
    done = subprocess.run(ASPOD + ["log", str(capture)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          timeout=600)
    command = clock.now() - start
    if done.returncode != 0:
        raise RuntimeError(f"aspod log failed: {done.stderr.decode()[-500:]}")
    lines = [f"decoding a capture of {frames:,} frames ({capture.stat().st_size / 1e6:.1f} MB):",
             f"  aspod log (subprocess, start-up included) {command:6.2f} s  {frames / command:9,.0f} frames/s",
             f"  SessionDecoder in process                 {in_process:6.2f} s  {frames / in_process:9,.0f} frames/s"]
    tshark = shutil.which("tshark")
    if tshark is None:
        return lines + ["  tshark: not installed, no figure beside (apt-get install tshark)"]
    lua = folder / "aspod.lua"
    lua.write_text(generate_dissector())
    start = clock.now()
    done = subprocess.run([tshark, "-n", "-X", f"lua_script:{lua}", "-r", str(capture), "-T", "fields",
                           "-e", "aspod.message"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, timeout=600)
    took = clock.now() - start
    decoded = done.stdout.count(b"\n")
    lines.append(f"  tshark + generated dissector              {took:6.2f} s  {frames / took:9,.0f} frames/s "
                 f"({decoded:,} frames listed); aspod log is {took / command:.1f}x as fast")
    return lines


def lockstep_session(path: Path, seconds: int, telemetry_hz: int = 50) -> None:
    """A lock-step session with its world (what `aspod replay` needs): telemetry, a ping a second, a move."""
    bench = LockstepBench(seed=3)
    bench.record(CaptureWriter.create(path, SessionInfo(clock="simulated", tool="bench", seed=3,
                                                        settings=bench.settings())))
    bench.connect()
    bench.call(M["SetTelemetryRate"](telemetry_hz))
    bench.call(M["Enable"]())
    bench.call(M["MoveBy"](1, 2.0, 2.0))
    for i in range(seconds):
        bench.call(M["Ping"](i))
        bench.run_for(1.0)
    bench.close()


def repeated_capture(session: Path, path: Path, size: int) -> Path:
    """About `size` bytes: `session`'s header, then its packets again and again (their times repeat)."""
    with SessionCapture.open(session) as capture:
        first = next(capture.frames()).offset
    data = session.read_bytes()
    body = data[first:]
    with open(path, "wb") as f:
        f.write(data[:first])
        for _ in range(max(1, (size - first) // len(body))):
            f.write(body)
    return path


def dense_telemetry_capture(session: Path, path: Path, size: int) -> Path:
    """`session`, then a TelemetryStatus and a TelemetryJoints of a new uptime every millisecond up to `size` bytes:
    what a replay reads, holds for its window, and judges (the replayed controller sends none of it)."""
    decoder = SessionDecoder(None)
    latest = {}
    with SessionCapture.open(session) as capture, open(path, "wb") as out:
        writer = PcapngWriter(out, comment=capture.info.to_comment())
        link = writer.add_interface("link")
        last_s = 0.0
        for f in capture.frames():
            writer.write_packet(link, f.time_s, f.data, DIRECTION_FLAG[f.direction], original_length=f.original_length)
            d = decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length)
            if d.name in ("TelemetryStatus", "TelemetryJoints"):
                latest[d.name] = d.message
            last_s = f.time_s
        n, start_ms = 0, round(last_s * 1000) + 1
        while out.tell() < size:
            for k, message in enumerate(latest.values()):
                fields = {**message.as_dict(), "uptime_ms": start_ms + n}
                payload = SCHEMA.encode(SCHEMA[message.spec.name].type(**fields))
                wire, _ = encode_signed(MsgClass.TELEMETRY, (2 * n + k) & 0xFFFF, 0, *payload, b"k" * 32, 2 * n + k + 1)
                writer.write_packet(link, (start_ms + n) / 1000.0, wire[1:-1], INBOUND)
            n += 1
    return path


def run_measured(args: list[str], keep_stdout: bool = False) -> tuple[int, str, str, int, float]:
    """`aspod ARGS` in a child: (exit status, stdout (if kept), stderr, its peak resident set in KiB, wall s)."""
    clock = RealClock()
    start = clock.now()
    done = subprocess.run([sys.executable, "-c", MEASURED, *args], text=True, stderr=subprocess.PIPE,
                          stdout=subprocess.PIPE if keep_stdout else subprocess.DEVNULL, timeout=3600)
    took = clock.now() - start
    found = re.search(r"peak_rss_kib (\d+)\s*$", done.stderr)
    if found is None:
        raise RuntimeError(f"aspod {' '.join(args)} did not say its peak: {done.stderr[-500:]}")
    return done.returncode, done.stdout or "", done.stderr, int(found.group(1)), took


def _peak(args: list[str], statuses: tuple[int, ...] = (0,)) -> tuple[float, float]:
    """(peak resident set in MB, wall seconds) of `aspod ARGS`; RuntimeError if it exits otherwise."""
    status, _, err, peak_kib, took = run_measured(args)
    if status not in statuses:
        raise RuntimeError(f"aspod {' '.join(args)}: exit status {status}: {err[-500:]}")
    return peak_kib * 1024 / 1e6, took


def capture_memory(folder: Path, quick: bool) -> list[str]:
    session = folder / "memory-session.pcapng"
    lockstep_session(session, 10)
    sizes = (16 * MIB,) if quick else (16 * MIB, 250 * MIB)
    lines = ["peak resident set against a capture's size (each command in a child; the small capture beside it):"]
    small = repeated_capture(session, folder / "memory-small.pcapng", 256 * 1024)
    for label, options in (("aspod log", []), ("aspod log --stats", ["--stats"]),
                           ("aspod log --plot", ["--plot", str(folder / "memory.png")])):
        base, _ = _peak(["log", str(small), *options])
        row = [f"  {label:<18} {small.stat().st_size / MIB:6.2f} MiB: {base:6.0f} MB"]
        for size in sizes:
            big = repeated_capture(session, folder / f"memory-{size // MIB}.pcapng", size)
            peak, took = _peak(["log", str(big), *options])
            row.append(f"{big.stat().st_size / MIB:.0f} MiB: {peak:.0f} MB ({peak - base:+.1f}) in {took:.0f} s")
        lines.append(";  ".join(row))
    recorded = folder / "memory-bench.pcapng"
    lockstep_session(recorded, 3)
    row: list[str] = []
    base: Optional[float] = None
    for size in (4 * MIB, 16 * MIB) if quick else (4 * MIB, 16 * MIB, 64 * MIB):
        capture = dense_telemetry_capture(recorded, folder / f"memory-dense-{size // MIB}.pcapng", size)
        peak, took = _peak(["replay", str(capture)], statuses=(0, 1))
        base = peak if base is None else base
        row.append(f"{capture.stat().st_size / MIB:.1f} MiB: {peak:.0f} MB ({peak - base:+.1f}) in {took:.0f} s")
    lines.append("  aspod replay       " + ";  ".join(row) + "  (dense telemetry; the lock-step world itself is most "
                 "of it)")
    for path in folder.glob("memory*"):
        path.unlink()
    return lines


def two_links(folder: Path, quick: bool) -> list[str]:
    fade_at, fade_s, block_at, block_s = (3.0, 4.0, 10.0, 2.0) if quick else (5.0, 30.0, 45.0, 10.0)
    end_s = block_at + block_s + 3.0
    env = _Env(folder)
    try:
        _, sim_url = env.start(["sim", "--link", "radio=pty", "--link", "optical=tcp:0", "--no-tracker"])
        links = dict(parse_links(sim_url))
        clock = RealClock()
        radio, radio_url = env.start(["proxy", "--controller", links["radio"], "--no-view", "--impair",
                                      f"radio,fade={fade_at}+{fade_s},seed=1"])
        origin_radio = clock.now()
        optical, optical_url = env.start(["proxy", "--controller", links["optical"], "--no-view", "--impair",
                                          f"optical,block={block_at}+{block_s},seed=2"])
        origin_optical = clock.now()
        client = HostClient(f"radio={radio_url},optical={optical_url}", env.key())
        samples: list[tuple[float, float]] = []
        failed = 0
        try:
            client.connect(20)
            token = 0
            while clock.now() - origin_radio < end_s:
                sent = clock.now()
                handle = client.call(M["Ping"](token & 0xFFFFFFFF), timeout_s=120)
                token += 1
                if handle.ok and handle.reply.token == (token - 1) & 0xFFFFFFFF:
                    samples.append((sent, handle.latency_s))
                else:
                    failed += 1
            executed = client.call(M["GetStatus"]()).reply.commands_executed
        finally:
            client.close()
        summaries = {name: proxy.stop(timeout_s=5)[1] for name, proxy in (("radio", radio), ("optical", optical))}
    finally:
        env.close()
    outside = [rtt for t, rtt in samples if not (fade_at <= t - origin_radio < fade_at + fade_s
                                                 or block_at <= t - origin_optical < block_at + block_s)]
    in_fade = [rtt for t, rtt in samples if fade_at <= t - origin_radio < fade_at + fade_s]
    in_block = [rtt for t, rtt in samples if block_at <= t - origin_optical < block_at + block_s]
    lost = {name: re.findall(r"(\d+) in fades, (\d+) in blockages", text) for name, text in summaries.items()}
    lines = [f"two links, every frame on both: radio fades {fade_s:g} s from {fade_at:g} s, optical blocked "
             f"{block_s:g} s from {block_at:g} s; {token} pings one after another",
             f"  commands lost (no answer): {failed} (goal 0); executed twice: {executed - token} (goal 0; the "
             f"controller counted {executed}, the host sent {token})",
             f"  frames the outages took: radio {sum(int(a) + int(b) for a, b in lost['radio'])}, "
             f"optical {sum(int(a) + int(b) for a, b in lost['optical'])}"]
    for label, part in (("outside the outages", outside), ("during the radio's fade", in_fade),
                        ("during the optical blockage", in_block)):
        if part:
            lines.append(f"  round trip {label:<28} p50 {pct(part, 0.5) * 1e3:6.2f} ms  p99 "
                         f"{pct(part, 0.99) * 1e3:6.2f} ms  max {max(part) * 1e3:6.2f} ms  (n={len(part)})")
    if in_fade and in_block and outside:
        base = statistics.median(outside)
        lines.append(f"  failover time (what an outage adds to a round trip): fade p50 "
                     f"{(pct(in_fade, 0.5) - base) * 1e3:+.2f} ms, p99 {(pct(in_fade, 0.99) - base) * 1e3:+.2f} ms; "
                     f"blockage p50 {(pct(in_block, 0.5) - base) * 1e3:+.2f} ms, p99 "
                     f"{(pct(in_block, 0.99) - base) * 1e3:+.2f} ms")
    return lines


def main(quick: bool = False) -> PartsResult:
    return run_parts("sessions: proxy overhead, capture decoding, memory against a capture's size, two links through "
                     "outages", (proxy_overhead, decode_speed, capture_memory, two_links), quick, "aspod-bench-sessions-")


if __name__ == "__main__":
    sys.exit(1 if main(quick="--quick" in sys.argv).error else 0)

