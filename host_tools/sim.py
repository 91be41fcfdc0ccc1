"""`aspod sim`: the controller and its plant in one process, in real time, on a real port.

Prints `ASPOD-LINK <url>` as its first line on stdout and `ASPOD-KEY <path>` as its
second, then runs until SIGINT or SIGTERM. Without --key-file it uses (creating it
if needed) the per-user development key that the host tools also default to.
"""
from __future__ import annotations

import argparse
import signal
import sys

from firmware_py.controller import ControllerConfig
from firmware_py.uart import DevicePort, PtyPort, TcpServerPort
from protocol import auth
from protocol.link import LinkConfig
from protocol.states import Fault
from timebase import RealClock

from host_tools.world import World


def run_sim(args: argparse.Namespace) -> int:
    if args.key_file is not None:
        psk, key_path = auth.load_key(args.key_file), args.key_file
    else:
        psk, key_path = auth.load_or_create_dev_key()
    if args.tcp is not None:
        port = TcpServerPort(args.tcp)
    elif args.port is not None:
        port = DevicePort(args.port, args.baud)
    else:
        port = PtyPort()
    link = LinkConfig(link_timeout_s=args.link_timeout, heartbeat_s=min(1.0, args.link_timeout / 3))
    config = ControllerConfig(link=link, telemetry_hz=args.telemetry_hz)
    world = World(RealClock(), port, psk, seed=args.seed, baud=args.baud, paced=not args.no_pacing,
                  controller_config=config)
    controller = world.controller

    def log_state(new, old, reason, now) -> None:
        print(f"aspod sim: uptime {controller.uptime_ms(now)} ms: {old.name} -> {new.name} ({reason.name}), "
              f"faults {Fault(controller.supervisor.faults).name or 'none'}", file=sys.stderr, flush=True)
    controller.state_listeners.append(log_state)
    print(f"ASPOD-LINK {port.url}", flush=True)
    print(f"ASPOD-KEY {key_path}", flush=True)
    print(f"aspod sim: controller up at {args.baud} baud{' (unpaced)' if args.no_pacing else ''}, "
          f"link timeout {args.link_timeout} s; Ctrl-C stops", file=sys.stderr, flush=True)
    stopping = []

    def stop(signum, frame):
        stopping.append(signum)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    try:
        world.scheduler.run_forever(lambda: bool(stopping))
    finally:
        world.close()
    return 0
