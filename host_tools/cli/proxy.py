"""`aspod proxy`: open both endpoints, print ASPOD-LINK for the host, forward until SIGINT/SIGTERM or an endpoint
goes away (host_tools/apps/proxy.py)."""
from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from protocol import auth
from host_tools.apps.proxy import EndpointGone, Proxy
from host_tools.cli.options import baud_rate
from host_tools.cli.settings import ProxySettings
from host_tools.client.control import simulator_key_file
from host_tools.exit_codes import EXIT_FAILED, EXIT_LINK, EXIT_OK
from host_tools.sessions.capture import CaptureWriter, SessionInfo
from host_tools.sessions.impairment import ImpairedLink
from host_tools.worlds.ports import open_endpoint

log = logging.getLogger("aspod")


def run_proxy(settings: ProxySettings) -> int:
    key_file = settings.key_file or simulator_key_file(settings.controller)      # a local simulator's, if it is one
    psk = None if key_file is None else auth.load_key(key_file, "--key-file" if settings.key_file else
                                                      f"the key file of the simulator serving {settings.controller}:")
    controller = open_endpoint(settings.controller, settings.baud)
    try:
        host = open_endpoint(settings.host, settings.baud)
    except BaseException:
        controller.close()
        raise
    capture = None
    if settings.record is not None:
        capture = CaptureWriter.create(settings.record, SessionInfo(clock="wall", tool="aspod proxy", settings={
            "host": settings.host, "controller": settings.controller, "impairment": settings.impairment.describe()}))
    proxy = Proxy(host, controller, ImpairedLink(settings.impairment), capture=capture, psk=psk,
                  view=sys.stdout if settings.view else None, capture_name=f"--record {settings.record}")
    print(f"ASPOD-LINK {host.url}", flush=True)
    log.info(f"aspod proxy: {host.url} (host) <-> {controller.url} (controller); link: "
             f"{settings.impairment.describe()}; Ctrl-C stops")
    stopping: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    signal.signal(signal.SIGINT, lambda signum, frame: stopping.append(signum))
    status = EXIT_OK
    try:
        proxy.run(lambda: bool(stopping))
        proxy.drain()                 # stopped: what is in flight (a host's Close, say) still reaches its end
    except EndpointGone as exc:
        log.error(f"aspod proxy: {exc}")
        status = EXIT_LINK
    finally:
        proxy.close()
        log.info(f"aspod proxy: {proxy.frames} frames\n{proxy.summary()}")
    if proxy.capture_failed and status == EXIT_OK:
        log.error(f"aspod proxy: {proxy.capture_failed}")
        status = EXIT_FAILED
    return status


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod proxy --controller /dev/pts/5",
    "aspod proxy --controller socket://127.0.0.1:5000 --host tcp:6000 --impair 'radio,seed=7' --record radio.pcapng",
]


def add_options(proxy: argparse.ArgumentParser) -> None:
    proxy.add_argument("--host", default="pty", metavar="ENDPOINT",
                       help="where the host connects: pty (a new pseudo-terminal, the default), tcp:PORT (tcp:0 picks "
                            "one), or a device or pyserial URL")
    proxy.add_argument("--controller", required=True, metavar="ENDPOINT",
                       help="the controller: the port aspod sim announced (/dev/pts/N, socket://127.0.0.1:PORT), a "
                            "device, a pyserial URL, or pty / tcp:PORT for a controller that connects itself")
    proxy.add_argument("--impair", default="clean", metavar="SPEC",
                       help="the link: a preset (clean, radio, optical) and/or key=value pairs: baud, latency_ms, "
                            "jitter_ms, ber, drop, dup, fade_every_s, fade_s, block_every_s, block_s, fade=START+S, "
                            "block=START+S, seed (e.g. 'radio,fade=60+30')")
    proxy.add_argument("--seed", type=int, default=None, help="the impairment's seed (overrides seed= in --impair)")
    proxy.add_argument("--baud", type=baud_rate, default=115200, help="line rate of a device endpoint (default 115200)")
    proxy.add_argument("--record", type=Path, metavar="FILE.pcapng",
                       help="capture every frame both ways as sent, each lost or damaged one with a comment")
    proxy.add_argument("--key-file", type=Path, default=None,
                       help="verify MACs in the live view with this key (default: that of the local simulator "
                            "serving --controller, if it is one)")
    proxy.add_argument("--no-view", action="store_true", help="no live view (the summary at the end only)")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_proxy(settings.proxy_settings(args))
