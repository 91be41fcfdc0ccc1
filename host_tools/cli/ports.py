"""`aspod ports`: where a host can connect: the serial ports (pyserial's `list_ports`) and this user's running
simulators (their links, processes and control endpoints), found as host tools find them
(host_tools/client/control.py `running_simulators`).

    aspod ports
    aspod ports --json
"""
from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from host_tools.exit_codes import EXIT_OK

if TYPE_CHECKING:
    from host_tools.client.control import Found


def serial_ports() -> list[dict]:
    """The serial ports pyserial lists here: device, description, hardware id."""
    from serial.tools import list_ports
    return [{"device": port.device, "description": port.description, "hwid": port.hwid}
            for port in sorted(list_ports.comports(), key=lambda port: port.device)]


def simulator_row(found: "Found") -> dict:
    info = found.info
    return {"link": info.get("link"), "pid": info.get("pid"), "plant": info.get("plant") is True,
            "control": str(found.path), "key": info.get("key")}


def port_lines(serial: list[dict], simulators: list[dict]) -> list[str]:
    """The text `aspod ports` prints: a line a port, none longer than it must be."""
    lines = ["serial ports:"]
    lines += [f"  {port['device']}  {port['description']}" for port in serial] or ["  none found"]
    lines.append("simulators (yours, running):")
    for sim in simulators:
        kind = "aspod sim" if sim["plant"] else "a controller (its plant elsewhere)"
        lines.append(f"  {sim['link']}  pid {sim['pid']}, {kind}")
        lines.append(f"    control {sim['control']}")
    if not simulators:
        lines.append("  none (aspod sim --pty starts one)")
    return lines


def list_ports_and_simulators(as_json: bool) -> int:
    from host_tools.client.control import running_simulators
    serial = serial_ports()
    simulators = [simulator_row(found) for found in running_simulators()]
    if as_json:
        print(json.dumps({"serial": serial, "simulators": simulators}, indent=2))
    else:
        print("\n".join(port_lines(serial, simulators)))
    return EXIT_OK


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod ports",
    "aspod ports --json",
]


def add_options(ports: argparse.ArgumentParser) -> None:
    ports.add_argument("--json", action="store_true", help="print one JSON object: serial, simulators")


def run(args: argparse.Namespace) -> int:
    return list_ports_and_simulators(args.json)
