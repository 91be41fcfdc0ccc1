"""`aspod replay FILE`: re-simulate a recorded session and report whether it matches (host_tools/apps/replay.py)."""
from __future__ import annotations

import contextlib
import json
import logging

from protocol import auth
from host_tools.apps.replay import ReplayError, replay
from host_tools.cli.log import open_capture
from host_tools.cli.settings import ReplaySettings
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK, EXIT_USAGE

log = logging.getLogger("aspod")


def run_replay(settings: ReplaySettings) -> int:
    capture = open_capture(settings.capture, "aspod replay")
    if capture is None:
        return EXIT_USAGE
    psk = None if settings.key_file is None else auth.load_key(settings.key_file, "--key-file")
    try:
        with capture, (settings.output.open() if settings.output is not None else contextlib.nullcontext()) as output:
            report = replay(capture, psk=psk, params=dict(settings.params), output=output)
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
