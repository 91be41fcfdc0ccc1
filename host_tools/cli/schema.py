"""`aspod schema`: the link protocol's declaration as data (protocol/declaration.py), for whoever generates the
other end of the link (a ground station, a controller's firmware) as MAVLink's ends are generated from its XML.

    aspod schema                           the protocol version, the schema hash and what the declaration holds
    aspod schema --json                    the whole declaration as JSON, on standard output (docs/schema.json)
    aspod schema --json --output FILE      the same, written to FILE whole or not at all

`--output` replaces an existing file only if it holds such a declaration already (`--force` for any other), and
never an input of the run (host_tools/outputs.py).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from host_tools.exit_codes import EXIT_OK
from host_tools.outputs import Kind, begins
from protocol import declaration

DECLARATION = Kind(f"a declaration of aspod schema's (it begins `{{\"format\": \"{declaration.FORMAT}\"`)",
                   begins(declaration.HEAD.encode()))


def summary(data: dict) -> str:
    """What `aspod schema` says without --json: the version, the hash and how much the declaration holds."""
    counts = {"messages": len(data["messages"]), "enumerations": len(data["enums"]),
              "constants": len(data["constants"])}
    held = ", ".join(f"{n} {what}" for what, n in counts.items())
    return (f"protocol v{data['protocol_version']}, schema hash {data['schema_hash']}: {held}\n"
            "aspod schema --json prints the whole declaration (format "
            f"{data['format']} {data['format_version']}; docs/schema.json)\n")


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod schema",
    "aspod schema --json > schema.json",
    "aspod schema --json --output schema.json",
]


def add_options(schema: argparse.ArgumentParser) -> None:
    schema.add_argument("--json", action="store_true",
                        help="print the whole declaration as JSON: framing, keys, types, every message and field "
                             "with offsets, enumerations, constants, the schema hash and how to recompute it")
    schema.add_argument("--output", "-o", type=Path, default=None, metavar="FILE.json",
                        help="write the JSON to FILE.json (whole or not at all) instead of standard output; only "
                             "with --json")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    output = settings.schema_output(args)
    data = declaration.declaration()
    if not args.json:
        sys.stdout.write(summary(data))
    elif output is None:
        sys.stdout.write(declaration.render(data))
    else:
        output.write_text(declaration.render(data))
        print(f"wrote {output}: protocol v{data['protocol_version']}, schema hash {data['schema_hash']}, "
              f"{len(data['messages'])} messages")
    return EXIT_OK
