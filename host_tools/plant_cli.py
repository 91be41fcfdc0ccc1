"""`aspod plant`: the plant alone, in real time, on a python-can interface.

It closes the loop around a controller in another process (`aspod firmware`, or
`aspod sim --hal`, which starts this as its child) or on other hardware. It prints

    ASPOD-PLANT ready interface=<interface> channel=<channel> [key=value ...] pid=<pid>

on stdout once its bus is open and its first tick is due, runs until SIGINT or SIGTERM
(or, with --stop-on-stdin-eof, until its standard input closes: the parent that
started it has gone), shuts the bus down and prints its counters on stderr:

    aspod plant: counters ticks=... frames_sent=... frames_received=... own_echoes=... bad_frames=... bus_errors=...

`frames_received` counts what other nodes sent: on udp_multicast the plant's own
frames come back to it and are dropped (`own_echoes`) before they are counted.

`PlantProcess` is the parent's side: start `aspod plant` as a child, wait for its
readiness line, notice if it dies, stop it.
"""
from __future__ import annotations

import argparse
import os
import select
import selectors
import signal
import subprocess
import sys
from typing import Any, Optional, Sequence

from firmware_py.scheduler import Scheduler
from timebase import RealClock

from host_tools import nodes

READY = "ASPOD-PLANT ready"
STDIN_CHECK_S = 0.1


def bus_options(args: argparse.Namespace) -> dict[str, Any]:
    """Keywords for `nodes.open_bus` from --bitrate, --data-bitrate and --bus-arg."""
    options = nodes.parse_bus_args(args.bus_arg or ())
    if args.bitrate is not None:
        options["bitrate"] = args.bitrate
    if args.data_bitrate is not None:
        options["data_bitrate"] = args.data_bitrate
    return options


def run_plant(args: argparse.Namespace) -> int:
    stopping: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    signal.signal(signal.SIGINT, lambda signum, frame: stopping.append(signum))
    options = bus_options(args)
    nodes.check_arm_settings(args.gravity, args.payload_kg)
    bus = nodes.open_bus(args.interface, args.channel, node=nodes.PLANT, **options)
    clock = RealClock()
    node = None
    started_s = clock.now()
    try:
        node = nodes.build_plant_node(bus, args.seed, gravity=args.gravity, payload_kg=args.payload_kg)
        scheduler = Scheduler(clock)
        scheduler.add("plant", node.step, period_s=node.period_s)
        if args.stop_on_stdin_eof:
            scheduler.add("stdin", _stdin_watch(stopping), tolerance_s=1.0)
        print(f"{READY} {nodes.describe_bus(args.interface, args.channel, options)} pid={os.getpid()}", flush=True)
        print(f"aspod plant: running on {args.interface} {args.channel}, seed {args.seed}, gravity {args.gravity}, "
              f"payload {args.payload_kg} kg; Ctrl-C stops", file=sys.stderr, flush=True)
        started_s = clock.now()
        scheduler.run_forever(lambda: bool(stopping))
    finally:
        bus.shutdown()
        if node is not None:
            counters = {"ticks": node.tick, **nodes.hal_counters(node), "dt_clamps": node.dt_clamps,
                        "output_expiries": node.plant.commanded.expiries}
            print(f"aspod plant: stopped after {clock.now() - started_s:.1f} s; counters "
                  f"{nodes.format_counters(counters)}", file=sys.stderr, flush=True)
            if node.last_bus_error is not None:
                print(f"aspod plant: last bus error: {node.last_bus_error}", file=sys.stderr, flush=True)
    return 0


def _stdin_watch(stopping: list[int]):
    """A task that stops the plant when standard input reaches end of file (its parent is gone)."""
    fd = sys.stdin.fileno()

    def step(now: float) -> Optional[float]:
        readable, _, _ = select.select([fd], [], [], 0)
        if readable:
            try:
                data = os.read(fd, 4096)
            except OSError:
                data = b""
            if not data:
                print("aspod plant: standard input closed (the parent is gone); stopping",
                      file=sys.stderr, flush=True)
                stopping.append(0)
                return None
        return now + STDIN_CHECK_S
    return step


class PlantProcess:
    """`aspod plant` as a child process of this one.

    Its stdin is a pipe this process holds, so the child stops by itself if this
    process dies without stopping it; its stderr (messages, counters at exit) is this
    process's stderr; it runs in a session of its own, so a Ctrl-C at the terminal
    reaches only this process, which then stops the child.
    """

    def __init__(self, interface: str, channel: str, options: dict[str, Any], *, seed: int = 0,
                 extra_args: Sequence[str] = (), start_timeout_s: float = 30.0) -> None:
        argv = [sys.executable, "-m", "host_tools.cli", "plant", "--interface", interface, "--channel", channel,
                "--seed", str(seed), "--stop-on-stdin-eof", *extra_args]
        for key, value in options.items():
            if key == "bitrate":
                argv += ["--bitrate", str(value)]
            elif key == "data_bitrate":
                argv += ["--data-bitrate", str(value)]
            else:
                argv += ["--bus-arg", f"{key}={value}"]
        self.argv = argv
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, bufsize=0,
                                     start_new_session=True)
        self.pid = self.proc.pid
        self.stopped = False       # we asked it to stop
        self.reported = False      # its unexpected end was reported
        try:
            self.ready_line = self._read_ready(start_timeout_s)
        except BaseException:
            self.stop()
            raise

    def _read_ready(self, timeout_s: float) -> str:
        line = bytearray()
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            while not line.endswith(b"\n"):
                if not sel.select(timeout_s):
                    raise OSError(f"the plant process (pid {self.pid}) did not say it was ready "
                                  f"within {timeout_s:g} s")
                byte = self.proc.stdout.read(1)
                if not byte:
                    status = self.proc.wait()
                    raise OSError(f"the plant process (pid {self.pid}) exited ({describe_exit(status)}) "
                                  "before it was ready; its messages are above")
                line += byte
        text = line.decode(errors="replace").rstrip("\n")
        if not text.startswith(READY):
            raise OSError(f"the plant process (pid {self.pid}) said {text!r}, not {READY!r}")
        return text

    def exit_status(self) -> Optional[int]:
        """None while it runs; its exit status (negative: killed by that signal) once it has ended."""
        return self.proc.poll()

    def stop(self, timeout_s: float = 10.0) -> Optional[int]:
        """SIGTERM, then SIGKILL if it has not gone within `timeout_s`; returns its exit status."""
        self.stopped = True
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None:
                stream.close()
        return self.proc.returncode


def describe_exit(status: int) -> str:
    if status < 0:
        try:
            name = signal.Signals(-status).name
        except ValueError:
            name = str(-status)
        return f"killed by {name}"
    return f"exit status {status}"
