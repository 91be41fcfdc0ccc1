"""`aspod proxy`: open both endpoints, print ASPOD-LINK for the host, forward until SIGINT/SIGTERM or an endpoint
goes away (host_tools/apps/proxy.py)."""
from __future__ import annotations

import logging
import signal
import sys

from protocol import auth
from host_tools.apps.proxy import EndpointGone, Proxy
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
