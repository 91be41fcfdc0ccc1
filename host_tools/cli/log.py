"""`aspod log FILE`: a session capture decoded, filtered, counted, tabled or plotted.

A capture that breaks part way (a truncated or corrupt block) is decoded up to the break, and the
break is reported with its byte offset; the exit status is then FAILED. A capture written with
another protocol schema is decoded as this build's, with a warning naming both hashes.
"""
from __future__ import annotations

import logging
import sys
from pathlib import Path

from protocol import auth
from protocol.files import InputFileError
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from host_tools.sessions.capture import SessionCapture, describe_world_event
from host_tools.sessions.decode import MAC_BAD, DecodedFrame, SessionDecoder, describe
from host_tools.sessions.export import plot_session, write_csv
from host_tools.sessions.stats import SessionStats
from host_tools.cli.settings import LogSettings

log = logging.getLogger("aspod.log")


def read_capture(path: Path, prog: str) -> SessionCapture | None:
    """The capture at `path`, or None when the file cannot be read (said on stderr)."""
    try:
        return SessionCapture.read(path)
    except OSError as exc:
        log.error(f"{prog}: cannot read {path}: {exc.strerror or exc}")
        return None
    except InputFileError as exc:          # missing, unreadable, a FIFO or device, larger than MAX_CAPTURE_BYTES
        log.error(f"{prog}: cannot read the capture {exc}")
        return None


def decode_capture(capture: SessionCapture, psk: bytes | None) -> list[DecodedFrame]:
    decoder = SessionDecoder(psk)
    return [decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length) for f in capture.frames]


def wanted(settings: LogSettings, d: DecodedFrame) -> bool:
    if settings.links and d.link not in settings.links:
        return False
    if settings.errors_only and not (d.error or d.mac == MAC_BAD):
        return False
    if settings.classes and d.class_name not in settings.classes:
        return False
    return not settings.messages or d.name in settings.messages


def run_log(settings: LogSettings) -> int:
    capture = read_capture(settings.capture, "aspod log")
    if capture is None:
        return EXIT_USAGE
    psk = None if settings.key_file is None else auth.load_key(settings.key_file, "--key-file")
    frames = decode_capture(capture, psk)
    origin = 0.0 if capture.info is not None and capture.info.clock in ("simulated", "paced") else (
        frames[0].time_s if frames else 0.0)
    shown = [d for d in frames if wanted(settings, d)]
    out = sys.stdout
    if capture.info is not None:
        info = capture.info
        print(f"# {settings.capture}: {len(capture.frames)} frames, recorded by {info.tool or 'an unnamed tool'} "
              f"on the {info.clock} clock" + (f", seed {info.seed}" if info.seed is not None else ""), file=out)
    for warning in capture.warnings:
        log.warning(f"aspod log: {settings.capture}: {warning}")
    if settings.stats:
        stats = SessionStats()
        for d in shown:
            stats.add(d)
        print(stats.report(), file=out)
    if settings.csv_to_stdout:
        write_csv(shown, out, origin)
    elif settings.csv is not None:
        with settings.csv.open(text=True) as table:
            rows = write_csv(shown, table, origin)
        print(f"# {rows} rows written to {settings.csv}", file=out)
    if settings.plot is not None:
        with settings.plot.open() as png:
            plot_session(shown, png, origin, title=Path(settings.capture).name)
        print(f"# plot written to {settings.plot}", file=out)
    if not (settings.stats or settings.csv is not None or settings.csv_to_stdout or settings.plot is not None):
        lines = [(d.time_s, describe(d, origin)) for d in shown]
        if not (settings.classes or settings.messages or settings.links or settings.errors_only):
            lines += [(t, f"{t - origin:12.6f} world    {describe_world_event(event)}")
                      for t, event, _ in capture.world_events]
        for _, line in sorted(lines, key=lambda item: item[0]):      # stable: frames and events in file order
            print(line, file=out)
    if capture.error is not None:
        log.error(f"aspod log: {settings.capture}: the capture breaks {capture.error} "
                  f"(decoded the {len(capture.frames)} frames before it)")
        return EXIT_FAILED
    return EXIT_OK
