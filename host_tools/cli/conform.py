"""`aspod conform URL`: the conformance suite (host_tools/conform/) against any controller speaking the link
protocol: a simulator on a pty or TCP, or a controller's firmware on a serial device.

    aspod conform /dev/pts/5                         every check; the simulator's own key, found from the URL
    aspod conform socket://127.0.0.1:40123 --skip-slow --junit conform.xml
    aspod conform /dev/ttyUSB0 --baud 115200 --key-file robot.key --only handshake --only nak-echo
    aspod conform --host --tcp 0                     the other side: play a controller, judge the host that connects

One line per check (PASS, FAIL or SKIP, its name, its level and the section of docs/protocol.md it tests; a
failure says what was expected and what came), then a summary. No check drives an output unless given
--allow-motion. Exit status: 0 every MUST passed, 1 a MUST failed, 2 bad usage, 3 the link cannot be opened, fails
during the run, or no controller answers under the key (with --host: no host sent anything) (docs/conformance.md).
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from host_tools.cli.options import add_link_args, bounded
from host_tools.exit_codes import EXIT_FAILED, EXIT_LINK, EXIT_OK, EXIT_USAGE

log = logging.getLogger("aspod")

EXAMPLES = [
    "aspod conform /dev/pts/5",
    "aspod conform socket://127.0.0.1:40123 --skip-slow --junit conform.xml",
    "aspod conform /dev/ttyUSB0 --key-file robot.key --baud 115200",
    "aspod conform /dev/pts/5 --only handshake --only nak-echo",
    "aspod conform --list",
    "aspod conform --host --tcp 0 --junit host.xml",
]


def add_options(conform: argparse.ArgumentParser) -> None:
    conform.add_argument("url", nargs="?", default=None, metavar="URL",
                         help="the controller's link: a device (/dev/pts/N, /dev/ttyUSB0) or a pyserial URL "
                              "(socket://HOST:PORT)")
    add_link_args(conform)
    conform.add_argument("--allow-motion", action="store_true",
                         help="also run the checks that drive outputs (Enable); without it none is sent")
    conform.add_argument("--skip-slow", action="store_true",
                         help="skip the slow checks (the link-loss failsafe waits out the link timeout; telemetry "
                              "and heartbeat rates are measured over seconds)")
    conform.add_argument("--only", action="append", default=[], metavar="NAME",
                         help="run only this check (repeatable; --list names them); the handshake runs first")
    conform.add_argument("--junit", type=Path, default=None, metavar="FILE.xml",
                         help="also write the results as JUnit XML (for CI), whole or not at all")
    conform.add_argument("--list", action="store_true", help="list the checks and the sections they test, and exit")
    host = conform.add_argument_group("--host: conform plays the controller, a host implementation connects")
    host.add_argument("--host", action="store_true",
                      help="serve a line (a new pty by default) as a controller, print ASPOD-LINK and ASPOD-KEY, and "
                           "judge the frames of the host that connects, once it is done (closed or gone)")
    where = host.add_mutually_exclusive_group()
    where.add_argument("--tcp", type=bounded(int, 0, 65535), default=None, metavar="PORT",
                       help="with --host: serve TCP on 127.0.0.1:PORT instead (0 picks a free port)")
    where.add_argument("--port", default=None, metavar="DEVICE", help="with --host: a real serial device instead")
    host.add_argument("--wait", type=bounded(float, 1.0, 3600.0), default=60.0, metavar="S",
                      help="with --host: stop when no host has sent anything for S seconds (default 60)")


def _selected(names: list[str]):
    from host_tools.conform.checks import CHECKS, by_name
    unknown = [n for n in names if n not in by_name()]
    if unknown:
        raise ValueError(f"--only: no check named {', '.join(unknown)}; the checks: "
                         f"{', '.join(c.name for c in CHECKS)}")
    if not names:
        return list(CHECKS)
    wanted = set(names) | {"handshake"}
    return [c for c in CHECKS if c.name in wanted]


def run(args: argparse.Namespace) -> int:
    from host_tools.conform.checks import CHECKS, Options
    if args.list:
        for c in CHECKS:
            marks = ", ".join(m for m, on in (("slow", c.slow), ("motion", c.motion)) if on)
            print(f"{c.name} ({c.level}, {c.cites}{', ' + marks if marks else ''}): {c.what}")
        return EXIT_OK
    if args.host:
        return run_host(args)
    if args.tcp is not None or args.port is not None:
        log.error("aspod conform: --tcp and --port are for --host (a URL names the controller's line)")
        return EXIT_USAGE
    if args.url is None:
        log.error("aspod conform: give the controller's link URL (aspod ports lists your simulators)")
        return EXIT_USAGE
    from host_tools.cli.settings import claims
    from host_tools.conform.junit import JUNIT
    checks = _selected(args.only)
    junit = claims(args).file(args.junit, "--junit", JUNIT)
    from host_tools.cli.main import host_key
    psk = host_key(args.key_file, args.url)
    from protocol.errors import LinkError
    from host_tools.conform.probe import Probe
    from host_tools.conform.runner import run_checks
    try:
        probe = Probe(args.url, psk, args.baud)
    except LinkError as exc:
        log.error(f"aspod conform: {exc}")
        return EXIT_LINK
    started = probe.now()
    print(f"aspod conform {args.url}: {len(checks)} checks"
          f"{'' if args.allow_motion else ' (no motion: --allow-motion to drive outputs)'}", flush=True)

    def report(result) -> None:
        print("\n".join(result.lines()), flush=True)

    try:
        results = run_checks(probe, checks, Options(args.allow_motion, args.skip_slow), report)
        if probe.up and probe.line_error is None:
            _close_session(probe)
        answered = probe.link.handshake_seen.verified > 0 or probe.link.sessions_started > 0
    finally:
        probe.close()
    elapsed_s = probe.now() - started
    musts = _summary(results, elapsed_s, junit, args.url)
    if probe.line_error is not None:
        log.error(f"aspod conform: the line to {args.url} failed: {probe.line_error}")
        return EXIT_LINK
    if not answered:
        log.error(f"aspod conform: no controller answered on {args.url} under this key (--key-file)")
        return EXIT_LINK
    return EXIT_FAILED if musts else EXIT_OK


def _summary(results, elapsed_s: float, junit, target: str) -> int:
    """Print the summary line, write the JUnit report if asked; the number of failed MUSTs."""
    from host_tools.conform.runner import FAIL, PASS, SKIP
    counts = {s: sum(r.status == s for r in results) for s in (PASS, FAIL, SKIP)}
    musts = sum(r.failed_must for r in results)
    print(f"{len(results)} checks in {elapsed_s:.1f} s: {counts[PASS]} passed, {counts[FAIL]} failed "
          f"({musts} MUST), {counts[SKIP]} skipped")
    if junit is not None:
        from host_tools.conform.junit import junit_xml
        junit.write_text(junit_xml(results, target, elapsed_s))
        print(f"wrote {junit}")
    sys.stdout.flush()
    return musts


def run_host(args: argparse.Namespace) -> int:
    """`--host`: serve a line as a controller, judge the host that connects (host_tools/conform/host_checks.py)."""
    if args.url is not None:
        log.error("aspod conform --host serves a line of its own: give no URL (--tcp PORT or --port DEVICE)")
        return EXIT_USAGE
    if args.only:
        log.error("aspod conform --host: --only chooses among the controller's checks; the host's all run")
        return EXIT_USAGE
    from host_tools.cli.settings import claims
    from host_tools.conform.junit import JUNIT
    junit = claims(args).file(args.junit, "--junit", JUNIT)
    from protocol import auth
    from timebase import RealClock
    from host_tools.conform.host_checks import judge_host, watch_host
    from host_tools.worlds.ports import open_endpoint
    from host_tools.worlds.runtime_folder import RuntimeFolder
    folder = None
    if args.key_file is not None:
        psk, key_path = auth.load_key(args.key_file, "--key-file"), args.key_file.absolute()
    else:
        folder = RuntimeFolder.open(log=log.info)
        psk, key_path = folder.new_key()
    try:
        spec = f"tcp:{args.tcp}" if args.tcp is not None else (args.port or "pty")
        port = open_endpoint(spec, args.baud)
        try:
            print(f"ASPOD-LINK {port.url}", flush=True)
            print(f"ASPOD-KEY {key_path}", flush=True)
            log.info(f"aspod conform --host: a controller on {port.url}; connect the host under test (it is judged "
                     f"once it closes its session or goes silent; {args.wait:g} s without a host ends the wait)")
            clock = RealClock()
            started = clock.now()
            watch = watch_host(port, psk, args.wait, clock=clock)
        finally:
            port.close()
    finally:
        if folder is not None:
            folder.close()
    if not any(s.from_host for s in watch.seen):
        log.error(f"aspod conform --host: no host sent anything on {port.url} in {args.wait:g} s")
        return EXIT_LINK
    results = judge_host(watch, lambda result: print("\n".join(result.lines()), flush=True))
    musts = _summary(results, clock.now() - started, junit, f"host on {port.url}")
    return EXIT_FAILED if musts else EXIT_OK


def _close_session(probe) -> None:
    """The suite's last session closed cleanly (Close), so the controller is left IDLE, not LINK_LOST."""
    import serial
    from protocol.link import LinkState
    try:
        probe.link.close(probe.now())
        probe.pump()
        probe.until(lambda: probe.link.state is not LinkState.CLOSING, 5.0)
    except (serial.SerialException, OSError) as exc:
        log.warning(f"aspod conform: closing the session: {exc}")
