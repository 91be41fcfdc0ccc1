"""`aspod replay FILE`: re-simulate a recorded session and report whether it matches (host_tools/apps/replay.py)."""
from __future__ import annotations

import argparse
import contextlib
import json
import logging
from pathlib import Path

from protocol import auth
from host_tools.apps.replay import ReplayError, replay
from host_tools.cli.log import open_capture
from host_tools.cli.settings import ReplaySettings
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from host_tools.progress import Progress

log = logging.getLogger("aspod")


def run_replay(settings: ReplaySettings) -> int:
    capture = open_capture(settings.capture, "aspod replay")
    if capture is None:
        return EXIT_USAGE
    psk = None if settings.key_file is None else auth.load_key(settings.key_file, "--key-file")
    try:
        with capture, (settings.output.open() if settings.output is not None else contextlib.nullcontext()) as output:
            with Progress("replay", None) as shown:
                report = replay(capture, psk=psk, params=dict(settings.params), output=output, shown=shown)
    except ReplayError as exc:
        log.error(f"aspod replay: {settings.capture}: {exc}")
        return EXIT_USAGE
    if settings.json:
        d = report.divergence
        print(json.dumps({"match": report.matches, "exact": report.exact, "commands": report.commands,
                          "replies": report.replies, "events": report.events, "telemetry": report.telemetry,
                          "telemetry_unmatched": report.telemetry_unmatched,
                          "identical_bytes": report.identical_bytes, "controller_frames": report.controller_frames,
                          "mac_failures": report.mac_failures, "uncertainty_ms": report.uncertainty_ms,
                          "real_time_factor": None if report.factor is None else dict(
                              zip(("overall", "least", "most"), report.factor)),
                          "divergence": None if d is None else {
                              "time_s": d.time_s, "message": d.message, "field": d.field,
                              "recorded": repr(d.recorded), "replayed": repr(d.replayed)}}, indent=1))
    else:
        print(report.describe())
    return EXIT_OK if report.matches else EXIT_FAILED


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod demo --record demo.pcapng && aspod replay demo.pcapng",
    "aspod replay sim.pcapng --param j1_kp=40 --output replayed.pcapng",
]


def add_options(replay_cmd: argparse.ArgumentParser) -> None:
    replay_cmd.add_argument("capture", type=Path, metavar="FILE", help="a capture from aspod sim or aspod demo --record")
    replay_cmd.add_argument("--param", action="append", metavar="NAME=VALUE",
                            help="change a controller parameter for the replay (repeatable): what would differ?")
    replay_cmd.add_argument("--key-file", type=Path, default=None,
                            help="the recording's pre-shared key: verify its MACs, and with it a simulated-clock "
                                 "replay is compared byte for byte too")
    replay_cmd.add_argument("--json", action="store_true", help="print one JSON object")
    replay_cmd.add_argument("--output", type=Path, default=None, metavar="FILE.pcapng",
                            help="also write the replay's own capture")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_replay(settings.replay_settings(args))
