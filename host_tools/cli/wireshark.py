"""`aspod wireshark`: write the Lua dissector for session captures (host_tools/sessions/wireshark.py)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional

from host_tools.exit_codes import EXIT_OK
from host_tools.outputs import Output
from host_tools.sessions.wireshark import generate_dissector


def run_wireshark(output: Optional[Output], installed: bool = False) -> int:
    text = generate_dissector()
    if output is None:
        sys.stdout.write(text)
    elif installed:
        output.write_text(text)
        print(f"installed {output}: Wireshark and tshark started from now on read captures with it "
              "(wireshark FILE.pcapng; tshark -r FILE.pcapng)")
    else:
        output.write_text(text)
        print(f"wrote {output}: open captures with  tshark -X lua_script:{output} -r FILE.pcapng  "
              "or install it with  aspod wireshark --install")
    return EXIT_OK


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod wireshark --install && wireshark session.pcapng",
    "aspod wireshark -o aspod.lua && tshark -X lua_script:aspod.lua -r session.pcapng",
]


def add_options(wireshark: argparse.ArgumentParser) -> None:
    where = wireshark.add_mutually_exclusive_group()
    where.add_argument("--output", "-o", type=Path, default=None, metavar="FILE.lua",
                       help="where to write it (default: standard output)")
    where.add_argument("--install", action="store_true",
                       help="write it as aspod.lua into your Wireshark's personal Lua plugins folder (as `tshark -G "
                            "folders` names it), so that Wireshark reads captures with it")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_wireshark(settings.wireshark_output(args), installed=args.install)
