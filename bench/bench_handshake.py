"""Handshakes under attack: a genuine host connecting through a flood of recorded Hellos, and through a loop of
keyless TCP connections (issue 34; docs/protocol_security.md).

1. **Recorded Hellos.** The lock-step bench's line at 115200 baud, paced: an attacker plays back 300 distinct
   recorded Hellos (of hosts that never got a session on this boot) in turn at 0, 5, 10, 20, 50 and 80 % of the
   line rate (quick: up to 20 %), and a new host connects four times in a row, a new nonce each, 1 s apart. Printed: connects that
   succeeded, the median and the longest connect, beside the same connect with no flood (goal: every connect
   within 3 s). Before the handshake's cookie, 300 recordings at 11 % kept every new host out (0 of 4).
2. **A keyless TCP connect loop.** A real `aspod sim --tcp 0`: a local loop opens (and closes) a connection every
   5 ms while a host connects four times in a row over TCP; the same without the loop. Before the port's
   admission by proof, the loop kept every host off (0 of 4).
"""
from __future__ import annotations

import os
import socket
import statistics
import threading
from pathlib import Path

from protocol import auth
from protocol.host_link import HostLink
from protocol.messages import MESSAGES as M
from bench import PartsResult, run_parts
from timebase import RealClock
from host_tools.client.live import HostClient
from host_tools.worlds.child import Child
from host_tools.worlds.world import LockstepBench

KEY = b"flood-bench-key-0123456789abcdef"
LINE_BYTES_PER_S = 115200 / 10
GOAL_S = 3.0
TRIES = 4


def recorded_hello(psk: bytes, nonce: bytes) -> bytes:
    """The Hello a genuine host with this nonce sends first, as an attacker records it off the line."""
    host = HostLink(psk, nonce_source=lambda: nonce)
    host.connect(0.0)
    host.poll(0.0)
    return host.take_all(0.0)


class HelloFlood:
    """An attacker's transmitter on a lock-step bench's line: `frames` in turn, `share` of the line rate on average."""

    def __init__(self, bench: LockstepBench, frames: list[bytes], share: float) -> None:
        self.bench, self.frames = bench, frames
        self.rate = share * LINE_BYTES_PER_S
        self.start_s = bench.clock.now()
        self.sent = 0
        self.count = 0
        bench.world.scheduler.add("attacker", self._step)

    def _step(self, now: float) -> float:
        while (due := self.start_s + self.sent / self.rate) <= now:
            frame = self.frames[self.count % len(self.frames)]
            self.bench.port.deliver(frame)
            self.sent += len(frame)
            self.count += 1
        return due

    def stop(self) -> None:
        self.bench.world.scheduler.remove("attacker")


def connects_through_hellos(distinct: int, share: float, tries: int = TRIES, seed: int = 5) -> list[float]:
    """A fresh bench flooded with `distinct` recorded Hellos at `share` of the line rate (none at 0); a new host
    connects `tries` times in a row, 1 s apart: the time of each connect that succeeded."""
    bench = LockstepBench(KEY, seed=seed)
    fresh = [recorded_hello(KEY, n.to_bytes(16, "little")) for n in range(1, distinct + 1)]
    flood = HelloFlood(bench, fresh, share) if share > 0 else None
    times = []
    try:
        bench.run_for(2.0)
        for _ in range(tries):
            began = bench.clock.now()
            if bench.connect(timeout_s=10.0) and bench.call(M["Ping"](1)).ok:
                times.append(bench.clock.now() - began)
            bench.run_for(1.0)
        if flood is not None:
            flood.stop()
    finally:
        bench.close()
    return times


def _row(label: str, times: list[float], baseline: float) -> str:
    if not times:
        return f"{label:<28} 0 of {TRIES} connected"
    worst = max(times)
    return (f"{label:<28} {len(times)} of {TRIES} connected; median {statistics.median(times) * 1e3:6.0f} ms, "
            f"longest {worst * 1e3:6.0f} ms ({worst / baseline:.1f}x the unflooded connect); "
            f"goal {GOAL_S:g} s {'met' if len(times) == TRIES and worst <= GOAL_S else 'MISSED'}")


def hello_flood(tmp: Path, quick: bool) -> list[str]:
    unflooded = connects_through_hellos(300, 0.0)
    baseline = max(unflooded)
    lines = [_row("no flood", unflooded, baseline)]
    for share in (0.05, 0.10, 0.20) + (() if quick else (0.50, 0.80)):
        lines.append(_row(f"300 recordings at {share:.0%}", connects_through_hellos(300, share), baseline))
    return lines


class ConnectLoop:
    """A keyless local loop: a connection to `url`'s TCP port opened and closed every `every_s`, from a thread, while
    the `with` block runs; `count` says how many were made."""

    def __init__(self, url: str, every_s: float = 0.005) -> None:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        self.address, self.every_s, self.count = (host, int(port)), every_s, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            try:
                socket.create_connection(self.address, timeout=5).close()
                self.count += 1
            except OSError:
                pass

    def __enter__(self) -> "ConnectLoop":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def _tcp_connects(url: str, psk: bytes) -> list[float]:
    clock, times = RealClock(), []
    for attempt in range(TRIES):
        began = clock.now()
        client = HostClient(url, psk)
        try:
            client.connect(timeout_s=30)
            if client.call(M["Ping"](attempt)).ok:
                times.append(clock.now() - began)
        except Exception:       # noqa: BLE001 (a connect that failed: counted by its absence)
            pass
        finally:
            client.close()
    return times


def tcp_connect_loop(tmp: Path, quick: bool) -> list[str]:
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp / "config")}
    sim = Child(["sim", "--tcp", "0", "--no-tracker", "--no-control"], env=env)
    try:
        url = sim.line(60).split(" ", 1)[1]
        psk = auth.load_key(sim.line(60).split(" ", 1)[1])
        unlooped = _tcp_connects(url, psk)
        baseline = max(unlooped or [float("nan")])
        with ConnectLoop(url) as loop:
            looped = _tcp_connects(url, psk)
        return [_row("TCP, no loop", unlooped, baseline),
                _row(f"TCP, loop every 5 ms ({loop.count} conn.)", looped, baseline)]
    finally:
        sim.stop()


def main(quick: bool = False) -> PartsResult:
    return run_parts("Handshakes under attack (issue 34)", [hello_flood, tcp_connect_loop], quick,
                     prefix="aspod-bench-handshake-")


if __name__ == "__main__":
    main()
