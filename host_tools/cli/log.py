"""`aspod log FILE`: a session capture decoded, filtered, counted, tabled or plotted.

The capture is read as a stream (`SessionCapture`): each frame is decoded, shown or counted and let go, so the
memory it takes is bounded whatever the file's size (the figure is in docs/sessions.md). A capture that breaks
part way (a truncated or corrupt block) is decoded up to the break, and the break is reported with its byte
offset; the exit status is then FAILED. A capture written with another protocol schema is decoded as this
build's, with a warning naming both hashes.
"""
from __future__ import annotations

import argparse
import logging
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Iterator, Optional

from protocol import auth
from protocol.files import InputFileError
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from host_tools.outputs import Output
from host_tools.sessions.capture import SessionCapture, WorldEvent, describe_world_event
from host_tools.sessions.decode import MAC_BAD, DecodedFrame, SessionDecoder, describe
from host_tools.sessions.export import SessionPlot, write_csv
from host_tools.sessions.foxglove import FoxgloveTopics, time_ns
from host_tools.sessions.stats import SessionStats

log = logging.getLogger("aspod.log")

if TYPE_CHECKING:
    from host_tools.cli.settings import LogSettings


def open_capture(path: Path, prog: str) -> Optional[SessionCapture]:
    """The capture at `path`, open to be read, or None when the file cannot be read (said on stderr)."""
    try:
        return SessionCapture.open(path)
    except InputFileError as exc:          # missing, unreadable, a FIFO, a device or a directory
        log.error(f"{prog}: cannot read the capture {exc}")
        return None


def decoded_frames(capture: SessionCapture, psk: Optional[bytes]) -> Iterator[DecodedFrame]:
    """The capture's frames decoded one at a time, in file order."""
    decoder = SessionDecoder(psk)
    for f in capture.frames():
        yield decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length)


def wanted(settings: LogSettings, d: DecodedFrame) -> bool:
    if settings.links and d.link not in settings.links:
        return False
    if settings.errors_only and not (d.error or d.mac == MAC_BAD):
        return False
    if settings.classes and d.class_name not in settings.classes:
        return False
    return not settings.messages or d.name in settings.messages


def mcap_topics(output: Output, finish: ExitStack) -> FoxgloveTopics:
    """Foxglove's topics written to `output` as MCAP (foxglove-sdk's writer, zstd chunks): the file is finished and
    put in place when `finish` closes, or left as it was when it closes on an error (host_tools/outputs.py)."""
    import foxglove
    pending = finish.enter_context(output.open())
    context = foxglove.Context()
    topics = FoxgloveTopics(context)
    finish.enter_context(foxglove.open_mcap(pending, context=context))
    return topics


def run_log(settings: LogSettings) -> int:
    capture = open_capture(settings.capture, "aspod log")
    if capture is None:
        return EXIT_USAGE
    with capture:
        return _log(settings, capture)


def _log(settings: LogSettings, capture: SessionCapture) -> int:
    psk = None if settings.key_file is None else auth.load_key(settings.key_file, "--key-file")
    where = f"aspod log: {settings.capture}"
    origin = 0.0
    if capture.info is None or capture.info.clock not in ("simulated", "paced"):    # Unix time: from the first frame
        origin = next((f.time_s for f in capture.frames()), 0.0)
    out = sys.stdout
    if capture.info is not None:
        info = capture.info
        print(f"# {settings.capture}: recorded by {info.tool or 'an unnamed tool'} on the {info.clock} clock"
              + (f", seed {info.seed}" if info.seed is not None else ""), file=out)
    for warning in capture.warnings:
        log.warning(f"{where}: {warning}")
    listing = not (settings.stats or settings.csv is not None or settings.csv_to_stdout or settings.plot is not None
                   or settings.mcap is not None)
    filtered = bool(settings.classes or settings.messages or settings.links or settings.errors_only)
    stats = SessionStats() if settings.stats else None
    plot = SessionPlot(origin) if settings.plot is not None else None
    decoder = SessionDecoder(psk)
    frames = events = 0
    said = set(capture.warnings)
    with ExitStack() as finish:
        topics = None if settings.mcap is None else mcap_topics(settings.mcap, finish)
        for item in capture.items():
            if isinstance(item, WorldEvent):
                events += 1
                if item.error:
                    log.warning(f"{where}: {item.error}; left out")
                elif listing and not filtered:
                    print(f"{item.time_s - origin:12.6f} world    {describe_world_event(item.event)}", file=out)
                continue
            frames += 1
            if item.note:
                log.warning(f"{where}: {item.note}")
            d = decoder.decode(item.data, item.time_s, item.link, item.direction, item.original_length)
            if not wanted(settings, d):
                continue
            if listing:
                print(describe(d, origin), file=out)
            if stats is not None:
                stats.add(d)
            if plot is not None:
                plot.add(d)
            if topics is not None:
                topics.add(d, time_ns(item.started_s, item.time_s))
    for warning in capture.warnings:           # found while reading (a packet without a direction)
        if warning not in said:
            log.warning(f"{where}: {warning}")
    if stats is not None:
        print(stats.report(), file=out)
    if settings.csv is not None or settings.csv_to_stdout:
        def shown() -> Iterator[DecodedFrame]:
            return (d for d in decoded_frames(capture, psk) if wanted(settings, d))
        if settings.csv_to_stdout:
            write_csv(shown, out, origin, settings.si)
        else:
            with settings.csv.open(text=True) as table:
                rows = write_csv(shown, table, origin, settings.si)
            print(f"# {rows} rows written to {settings.csv}", file=out)
    if plot is not None:
        with settings.plot.open() as png:
            plot.save(png, title=Path(settings.capture).name)
        print(f"# plot written to {settings.plot}", file=out)
    if topics is not None:
        written = ", ".join(f"{n} on {topic}" for topic, n in topics.counts.items() if n) or "no message"
        print(f"# MCAP written to {settings.mcap}: {written}", file=out)
    if listing:
        print(f"# {frames} frames" + (f", {events} world events" if events else ""), file=out)
    if capture.error is not None:
        log.error(f"{where}: the capture breaks {capture.error} (decoded the {frames} frames before it)")
        return EXIT_FAILED
    return EXIT_OK


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod log session.pcapng",
    "aspod log session.pcapng --class command --class event",
    "aspod log session.pcapng --stats",
    "aspod log session.pcapng --message TelemetryJoints --csv joints.csv",
    "aspod log session.pcapng --plot session.png --key-file link.key",
    "aspod log session.pcapng --mcap session.mcap",
]


def add_options(log_cmd: argparse.ArgumentParser) -> None:
    log_cmd.add_argument("capture", type=Path, metavar="FILE", help="a capture written by --record or aspod proxy")
    log_cmd.add_argument("--class", dest="cls", action="append", metavar="CLASS",
                         help="only frames of this class (link, command, urgent, telemetry, event); repeatable")
    log_cmd.add_argument("--message", action="append", metavar="NAME",
                         help="only this message (e.g. TelemetryJoints); repeatable")
    log_cmd.add_argument("--link", action="append", metavar="NAME", help="only frames of this link; repeatable")
    log_cmd.add_argument("--errors", action="store_true", help="only frames that failed to decode or verify")
    log_cmd.add_argument("--stats", action="store_true",
                         help="counts instead: frames, errors, round trips, retransmissions, losses per class")
    log_cmd.add_argument("--csv", type=Path, metavar="FILE.csv",
                         help="write the decoded messages as CSV (- for stdout): a column a field, its unit in the "
                              "header (degrees, as the console shows them), states, modes and faults by name")
    log_cmd.add_argument("--si", action="store_true", help="with --csv: angles in radians and lengths in metres")
    log_cmd.add_argument("--plot", type=Path, metavar="FILE.png",
                         help="plot joint positions and currents, the tracker's pointing error and link health")
    log_cmd.add_argument("--mcap", type=Path, metavar="FILE.mcap",
                         help="write the session as MCAP for Foxglove: joint states, the arm as a 3D scene, the "
                              "tracker's pointing, events as log lines (the foxglove extra; docs/sessions.md)")
    log_cmd.add_argument("--key-file", type=Path, default=None,
                         help="pre-shared key file (hex): verify every frame's MAC (without it MACs are not checked)")


def run(args: argparse.Namespace) -> int:
    from host_tools.cli import settings
    return run_log(settings.log_settings(args))
