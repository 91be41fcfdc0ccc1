"""`aspod demo` (what `make demo` runs): the arm picks up debris and drops it in the bin.

By default it runs the pick-and-place (`host_tools/apps/pick_place.py`) on the simulated clock,
faster than real time, and prints each step with the gripper's positioning error against
the report's 1 cm; `--json` prints one JSON object instead; `--gravity orbit` runs it
without gravity.

`--link` runs the link demo instead: it starts `aspod sim --pty` as a subprocess, reads the
ASPOD-LINK and ASPOD-KEY lines, runs the script below over the printed port exactly as
`aspod teleop --script` would, and prints a summary: round-trip times, frames and errors at
both ends.
"""
from __future__ import annotations

import json
import logging
import sys
from dataclasses import dataclass
from typing import Optional

from protocol import auth
from protocol.errors import LinkError
from protocol.reasons import Reason

from host_tools.apps import pick_place
from host_tools.client.live import HostClient
from host_tools.exit_codes import EXIT_FAILED, EXIT_LINK, EXIT_OK
from host_tools.outputs import Output
from host_tools.progress import Progress
from host_tools.teleop.session import run_script
from host_tools.worlds.child import Child, ChildError

log = logging.getLogger("aspod")

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


@dataclass(frozen=True)
class DemoSettings:
    """`aspod demo`: gravity and seed of the pick-and-place; `json` output; `link`: the link demo at `baud`."""
    gravity: str = "earth"
    seed: int = 0
    json: bool = False
    link: bool = False
    baud: int = 115200
    record: Optional[Output] = None   # the session's capture (on the simulated clock: aspod replay re-runs it exactly)


def run_demo(settings: DemoSettings) -> int:
    if settings.link:
        return run_link_demo(settings)
    if settings.json:
        with Progress("demo", pick_place.SIM_S) as shown:
            report = pick_place.run(settings.gravity, settings.seed, record=settings.record, shown=shown)
        print(json.dumps(report, indent=1))
        return EXIT_OK if report["within_spec"] else EXIT_FAILED
    print(f"pick and place, gravity {settings.gravity}, on the simulated clock (spec: within "
          f"{pick_place.SPEC_M * 100:.0f} cm at the gripper)", flush=True)

    def progress(result: pick_place.StepResult) -> None:
        print(f"  {result.name:<16} error {result.position_error_m * 1000:7.3f} mm   "
              f"({result.sim_time_s:6.2f} s simulated)", flush=True)
    with Progress("demo", pick_place.SIM_S) as shown:
        report = pick_place.run(settings.gravity, settings.seed, progress, record=settings.record, shown=shown)
    if report["error"]:
        log.error(f"aspod demo: {report['error']}")
    worst = report["max_position_error_m"]
    print(f"max position error {'-' if worst is None else f'{worst * 1000:.3f}'} mm; "
          f"{report['sim_time_s']:.1f} s simulated in {report['wall_time_s']:.1f} s wall "
          f"({report['speed_x_real_time']}x real time)")
    print("demo " + ("ok" if report["within_spec"] else "FAILED"))
    return EXIT_OK if report["within_spec"] else EXIT_FAILED


def run_link_demo(settings: DemoSettings) -> int:
    try:
        sim = Child(["sim", "--pty", "--baud", str(settings.baud)], stderr=None)
    except OSError as exc:
        raise LinkError(Reason.NO_SESSION, f"the simulator did not start: {exc}") from None
    try:
        try:
            link_line, key_line = sim.line(START_TIMEOUT_S), sim.line(START_TIMEOUT_S)
        except ChildError as exc:
            raise LinkError(Reason.NO_SESSION, f"the simulator printed nothing: {exc}") from None
        print(link_line)
        print(key_line)
        if not link_line.startswith("ASPOD-LINK ") or not key_line.startswith("ASPOD-KEY "):
            log.error("aspod demo: the simulator did not announce its port and key")
            return EXIT_LINK
        url, key_path = link_line.split(" ", 1)[1], key_line.split(" ", 1)[1]
        client = HostClient(url, auth.load_key(key_path), baud=settings.baud)
        try:
            client.connect()
            print(f"link up over {url} at {settings.baud} baud (8N1 wire time emulated)\n", flush=True)
            status, session = run_script(client, SCRIPT.splitlines(), sys.stdout)
            print("\n--- summary ---")
            print(session.summary())
            print("demo " + ("ok" if status == EXIT_OK else "FAILED"))
            return status
        finally:
            client.close()
    finally:
        sim.stop()
