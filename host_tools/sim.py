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
from protocol.reasons import Reason
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
    params_path = args.params if args.params is not None else auth.default_key_path().with_name("params.json")
    timeout_s = args.link_timeout if args.link_timeout is not None else LinkConfig.link_timeout_s
    link = LinkConfig(link_timeout_s=timeout_s, heartbeat_s=min(LinkConfig.heartbeat_s, timeout_s / 3))
    config = ControllerConfig(link=link, params_path=params_path)
    world = World(RealClock(), port, psk, seed=args.seed, baud=args.baud, paced=not args.no_pacing,
                  controller_config=config)
    params = world.controller.params
    for problem in params.load_problems:
        print(f"aspod sim: parameters: {problem}", file=sys.stderr, flush=True)
    # what the command line says wins over the saved set
    for name, value in (("link_timeout_s", args.link_timeout), ("telemetry_hz", args.telemetry_hz)):
        if value is not None:
            reason, detail = params.set(name, value)
            if reason is not Reason.OK:
                raise ValueError(f"--{name}: {detail}")
    world.controller.telemetry_hz = int(params["telemetry_hz"])
    controller = world.controller

    def log_state(new, old, reason, now) -> None:
        print(f"aspod sim: uptime {controller.uptime_ms(now)} ms: {old.name} -> {new.name} ({reason.name}), "
              f"faults {Fault(controller.supervisor.faults).name or 'none'}", file=sys.stderr, flush=True)
    controller.state_listeners.append(log_state)
    print(f"ASPOD-LINK {port.url}", flush=True)
    print(f"ASPOD-KEY {key_path}", flush=True)
    print(f"aspod sim: controller up at {args.baud} baud{' (unpaced)' if args.no_pacing else ''}, "
          f"link timeout {params['link_timeout_s']} s, parameters in {params_path}; Ctrl-C stops",
          file=sys.stderr, flush=True)
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
