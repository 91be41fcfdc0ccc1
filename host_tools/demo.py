"""`aspod demo` (what `make demo` runs): a simulator on a pty and a scripted teleop session.

It starts `aspod sim --pty` as a subprocess, reads the ASPOD-LINK and ASPOD-KEY lines,
runs the script below over the printed port exactly as `aspod teleop --script` would,
and prints a summary: round-trip times, frames and errors at both ends.
"""
from __future__ import annotations

import argparse
import selectors
import subprocess
import sys

from protocol import auth
from protocol.errors import LinkError
from protocol.reasons import Reason

from host_tools.client import HostClient
from host_tools.teleop import EXIT_LINK, EXIT_OK, run_script

SCRIPT = """\
# a short session: link check, enable, e-stop while enabled, recover
ping
status
enable
status
ping 1
ping 2
ping 3
estop
status
reset
status
telemetry 20
watch 2
link
"""
START_TIMEOUT_S = 30.0


def _read_line(proc: subprocess.Popen) -> str:
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(START_TIMEOUT_S):
            raise LinkError(Reason.NO_SESSION, "the simulator printed nothing")
    return proc.stdout.readline().decode().strip()


def run_demo(args: argparse.Namespace) -> int:
    sim = subprocess.Popen([sys.executable, "-m", "host_tools.cli", "sim", "--pty", "--baud", str(args.baud)],
                           stdout=subprocess.PIPE, bufsize=0)
    try:
        link_line, key_line = _read_line(sim), _read_line(sim)
        print(link_line)
        print(key_line)
        if not link_line.startswith("ASPOD-LINK ") or not key_line.startswith("ASPOD-KEY "):
            print("aspod demo: the simulator did not announce its port and key", file=sys.stderr)
            return EXIT_LINK
        url, key_path = link_line.split(" ", 1)[1], key_line.split(" ", 1)[1]
        client = HostClient(url, auth.load_key(key_path), baud=args.baud)
        try:
            client.connect()
            print(f"link up over {url} at {args.baud} baud (8N1 wire time emulated)\n", flush=True)
            status, session = run_script(client, SCRIPT.splitlines(), sys.stdout)
            print("\n--- summary ---")
            print(session.summary())
            print("demo " + ("ok" if status == EXIT_OK else "FAILED"))
            return status
        finally:
            client.close()
    finally:
        sim.terminate()
        try:
            sim.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.wait()
