"""The `aspod teleop` command: connect, then a script or an interactive console, then close the session.

Every way out closes the session cleanly (`HostClient.close`: an authenticated Close, so the controller goes
to IDLE rather than latching LINK_LOST): `quit`, Ctrl-D, the end of a script (DONE), Ctrl-C or SIGTERM
(STOPPED; SIGTERM reaches here as cli/main.py's SystemExit, exit 143), an exception (ERROR).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from typing import TYPE_CHECKING

from host_tools.cli.options import add_link_args, bounded
from host_tools.exit_codes import EXIT_USAGE

if TYPE_CHECKING:
    from host_tools.cli.settings import TeleopSettings


log = logging.getLogger("aspod")


def run_teleop(args: TeleopSettings) -> int:
    # imported here, not at the top: `aspod teleop --help` loads neither numpy nor the plant
    from host_tools.cli.main import host_key
    from host_tools.client.control import open_control
    from host_tools.client.live import HostClient
    from host_tools.sessions.capture import CaptureWriter, SessionInfo
    from host_tools.teleop.console import interactive_console
    from host_tools.teleop.format import for_terminal
    from host_tools.teleop.record import ScriptRecord
    from host_tools.teleop.session import TeleopError, check_script, run_script
    from host_tools.teleop.words import read_script
    from protocol.states import CloseWhy
    lines = None
    if args.script is not None or not sys.stdin.isatty():
        try:
            lines = read_script(args.script, sys.stdin.buffer)
        except TeleopError as exc:
            log.error(f"aspod teleop: {exc}")
            return EXIT_USAGE
    if lines is not None:
        _steps, problems = check_script(lines)
        if problems:
            for problem in problems:
                log.error(f"aspod teleop: error: {problem}")
            log.error("aspod teleop: script not run: nothing was sent")
            return EXIT_USAGE
    psk = host_key(args.key_file, args.url)      # once the script is known good: nothing is opened before
    capture = None
    if args.record is not None:
        capture = CaptureWriter.create(args.record, SessionInfo(clock="wall", tool="aspod teleop",
                                                                settings={"url": args.url, "baud": args.baud}))
    control = None
    try:
        control = open_control(args.url, args.control)
        client = HostClient(args.url, psk, baud=args.baud, capture=capture, control=control)
    except BaseException:
        if capture is not None:
            capture.close()
        if control is not None:
            control.close()
        raise
    clients = [client]

    def open_client(url: str) -> HostClient:
        """`connect URL` at the console: a new client on URL, with its simulator's key (or --key-file) and its
        control endpoint (--control names the first link's), writing on into the same capture."""
        control = open_control(url, args.control if url == args.url else None)
        try:
            clients.append(HostClient(url, host_key(args.key_file, url), baud=args.baud, capture=capture,
                                      control=control))
        except BaseException:
            if control is not None:
                control.close()
            raise
        return clients[-1]
    why = CloseWhy.DONE
    try:
        client.connect(args.connect_timeout_s)
        info = client.link.controller_info
        link_line = (f"link up: {args.url}, protocol v{info.protocol_version}, schema {info.schema_hash:016x}, "
                     f"controller link timeout {info.link_timeout_ms} ms")
        control_line = None if control is None else f"the simulator's control endpoint: {control.path}"
        if args.json and lines is not None:          # one JSON object on stdout, nothing else
            record = ScriptRecord()
            status, session = run_script(client, lines, sys.stdout, keep_going=args.keep_going, record=record)
            print(json.dumps(record.as_dict(session, status, script=str(args.script or "-"), target=args.url,
                                            link=link_line, control=None if control is None else str(control.path)),
                             indent=1), flush=True)
            return status
        print(for_terminal(link_line, sys.stdout), flush=True)
        if control_line is not None:
            print(for_terminal(control_line, sys.stdout), flush=True)
        if lines is not None:
            status, session = run_script(client, lines, sys.stdout, keep_going=args.keep_going)
        else:
            status, session = interactive_console(client, opener=open_client)
        if args.summary or lines is None:
            print(for_terminal(session.summary(), sys.stdout), flush=True)
        return status
    except (KeyboardInterrupt, SystemExit):      # Ctrl-C, or SIGTERM (cli/main.py: SystemExit(143))
        why = CloseWhy.STOPPED
        raise
    except BaseException:
        why = CloseWhy.ERROR
        raise
    finally:
        for each in reversed(clients):        # the one in use; those `connect URL` replaced are closed already
            each.close(why)


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod teleop",
    "aspod teleop /dev/pts/5",
    "aspod teleop socket://127.0.0.1:5555 --script session.txt --summary",
]


def add_options(teleop: argparse.ArgumentParser) -> None:
    teleop.add_argument("url", nargs="?", default=None,
                        help="pyserial URL or device: /dev/pts/N, socket://HOST:PORT, ...; default: your one running "
                             "simulator (aspod ports lists them)")
    add_link_args(teleop)
    teleop.add_argument("--script", type=Path, metavar="FILE", help="run the commands in FILE and exit")
    teleop.add_argument("--keep-going", action="store_true", help="in a script, go on after a failed command")
    teleop.add_argument("--connect-timeout", type=bounded(float, 0.1, 600), default=10.0, metavar="S")
    teleop.add_argument("--summary", action="store_true", help="print link figures at the end")
    teleop.add_argument("--json", action="store_true",
                        help="with a script: print one JSON object (each line's outcome and output, the motions, "
                             "the round trips) instead of the session's text")
    teleop.add_argument("--record", type=Path, metavar="FILE.pcapng",
                        help="capture every frame both ways, as this host sent and received them (aspod log)")
    teleop.add_argument("--control", type=Path, metavar="PATH",
                        help="the simulator's control endpoint, for `sim` lines (default: the one of the aspod sim "
                             "that serves URL, if any)")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_teleop(settings.teleop_settings(args))
