"""The one-process world's HAL bus, written to a file by python-can's own `Logger` (`aspod sim --can-log`).

The two nodes of a one-process world meet on a private in-process bus that no outside tool can
join (host_tools/worlds/local_bus.py), and hand each other values rather than bytes. This
writes every frame either node sends as the `can.Message` real CAN would carry (a value frame
packed now, `ValueFrame.data`), stamped with the world's time, through `can.Logger`: the file's
suffix chooses the format (.blf, .asc, .log, .csv, .trc, .txt), and `cantools decode`,
`python -m can.viewer`, `python -m can.player` and `cantools plot` read it with
`protocol/hal.dbc`. `--can-only`/`--can-skip` keep some messages only (`message_ids`). Most of the bus
is the 1 kHz MOTOR_CMD, MOTOR_FB and PLANT_SYNC: measured, 3 minutes of the world (647,574 frames) made
a 45.9 MB candump .log and a 4.72 MB .blf (zlib-compressed, 9.7 times smaller), and without those three
4.63 MB and 0.69 MB, so a long run is best logged as .blf, without them, or in parts.

The log is written to a temporary file with the same suffix beside it and put in place by
`stop` (host_tools/outputs.py), so a run that is killed leaves the destination as it was.

Rotation (`--can-rotate-mb`, `rotate_bytes`): python-can's own `SizedRotatingLogger` closes the file once it
holds `rotate_bytes` or more (checked before each frame, so a part is at most one frame larger) and goes on in a
new one. python-can would rename the full file `<stem>_<local wall time>_#NNN<suffix>` and keep writing the
newest frames under the name given; here the wall time is left out (`part_path`): `hal.log` is written as
`hal_#000.log`, `hal_#001.log`, ... in the order of their frames, and the newest frames, the last part, are
`hal.log` itself, put in place by `stop` as without rotation. So names are known before the run and say the
order, whatever the machine's clock. Each full part is flushed to the disk and renamed into place at once, under
a name no file had (made with O_EXCL: never over another file, whatever `--force`): it can be read while the run
goes on, and a run killed outright leaves the parts it finished, its last part in the temporary, and the
destination as it was. The parts of a run are claimed with its settings (`Claims.series`): a run is refused if a
file of those names is already there (an earlier run's parts, which its own would mix with) or is an input or
another output of the run.
"""
from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Iterable, Optional

import can

from timebase import Clock

from host_tools.outputs import Kind, Output, begins

# What python-can's Logger writes for each suffix, known by how the file begins (an existing --can-log file that
# begins otherwise is not overwritten without --force).
KINDS = {
    ".asc": Kind("a Vector ASC log (it begins `date `)", begins(b"date ")),
    ".blf": Kind("a Vector BLF log", begins(b"LOGG")),
    ".csv": Kind("a python-can CSV log", begins(b"timestamp,arbitration_id,")),
    ".log": Kind("a candump log (lines such as `(1.500000) plant 123#0102`)", begins(b"(")),
    ".trc": Kind("a PCAN trace", begins(b";$FILEVERSION")),
    ".txt": Kind("a python-can text log (lines that begin `Timestamp:`)", begins(b"Timestamp:")),
}
# What python-can's SizedRotatingLogger writes (its `_supported_formats`, less .db which --can-log does not take):
# not .trc.
ROTATED = (".asc", ".blf", ".csv", ".log", ".txt")
MEGABYTE = 1_000_000      # --can-rotate-mb counts these, as `ls --si` and the sizes in docs/sessions.md do


def part_path(path: Path, index: int) -> Path:
    """The name of the `index`th full part (from 0) of a rotated log at `path`: `hal.log` -> `hal_#000.log`
    (python-can's count, without its wall time)."""
    return path.with_name(f"{path.stem}_#{index:03}{path.suffix}")


def part_names(path: Path) -> "re.Pattern[str]":
    """The file names `part_path` gives beside `path`, any count (a fourth digit after #999, as python-can's)."""
    return re.compile(re.escape(path.stem) + r"_#\d{3,}" + re.escape(path.suffix))


class SizedRotatingLog(can.SizedRotatingLogger):
    """python-can's SizedRotatingLogger, which looks at the file's size less often: only when the frames written
    since it last looked could have brought it to `max_bytes`. It rotates before the same frames (each frame adds
    less than `FRAME_BYTES_MAX`). For a text format, python-can's `file_size` is `tell()`, which flushes the file: a
    write for every frame. Measured, 3 minutes of the world logged to .log in parts of 10 MB took 83 s with
    python-can's own check at every frame, 52 s so, 53 s in one file: the same parts, to the byte."""

    FRAME_BYTES_MAX = 1024      # more than any format writes for a frame (the widest: .asc, 64 data bytes, 338)

    def __init__(self, base_filename: str, max_bytes: int, **kwargs) -> None:
        super().__init__(base_filename, max_bytes, **kwargs)
        self._unchecked = 0         # frames still to come before the size is looked at again

    def should_rollover(self, msg: can.Message) -> bool:
        if self._unchecked:
            self._unchecked -= 1
            return False
        size = self.writer.file_size() if self.max_bytes > 0 else None
        if size is None:
            return False
        if size >= self.max_bytes:
            return True
        self._unchecked = (self.max_bytes - 1 - size) // self.FRAME_BYTES_MAX     # (this frame is written now)
        return False


class HalBusLog:
    """Logs what `buses` send from now on (of `ids` only, if given: a filter by message); `stop()` closes the file
    and puts it in place."""

    def __init__(self, output: Output, clock: Clock, buses: dict[str, can.BusABC],
                 ids: Optional[frozenset[int]] = None, rotate_bytes: Optional[int] = None) -> None:
        self._ids = ids
        self._pending = output.open()
        self.parts: list[Path] = []          # the full parts put in place so far (rotation), in order
        try:
            self._mode = stat.S_IMODE(os.stat(self._pending.path).st_mode)   # the destination's, or a new file's
            if rotate_bytes is None:
                self._logger = can.Logger(str(self._pending.path))     # the temporary's suffix picks the format
            else:
                self._logger = self._rotating(output.destination, rotate_bytes)
        except BaseException:
            self._pending.discard()
            raise
        self._clock = clock
        self.frames = 0
        for channel, bus in buses.items():
            self._tap(bus, channel)

    def _tap(self, bus: can.BusABC, channel: str) -> None:
        send = bus.send

        ids = self._ids

        def logged_send(msg, timeout=None):
            result = send(msg, timeout)        # a send the bus refuses raises before it is logged
            if ids is not None and msg.arbitration_id not in ids:
                return result
            layout = getattr(msg, "layout", None)      # a ValueFrame: its layout says what real CAN would carry
            is_fd = layout.is_fd if layout is not None else msg.is_fd
            self._logger.on_message_received(can.Message(
                timestamp=self._clock.now(), arbitration_id=msg.arbitration_id, data=bytes(msg.data),
                is_extended_id=msg.is_extended_id, is_fd=is_fd, bitrate_switch=is_fd, channel=channel))
            self.frames += 1
            return result

        bus.send = logged_send       # the HAL endpoints look `send` up on the bus at every frame

    def _rotating(self, destination: Path, rotate_bytes: int) -> can.SizedRotatingLogger:
        """python-can's SizedRotatingLogger on the temporary, its full parts put in place beside `destination`."""
        logger = SizedRotatingLog(str(self._pending.path), max_bytes=rotate_bytes)
        logger.namer = lambda default: str(part_path(destination, logger.rollover_count))   # counted from 0
        logger.rotator = self._put_in_place
        return logger

    def _put_in_place(self, full: str, part: str) -> None:
        """A rotator for SizedRotatingLogger: the part it has closed, `full` (the temporary), onto the disk and
        renamed to `part`, a name no file has (never over one), with the mode a new file gets."""
        fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
        try:
            mode = stat.S_IMODE(os.fstat(fd).st_mode)
        finally:
            os.close(fd)
        try:
            _sync(full)
            os.chmod(full, mode)
            os.replace(full, part)              # over the empty file just made, in one step
        except BaseException:
            os.unlink(part)
            raise
        self.parts.append(Path(part))

    @property
    def files(self) -> list[Path]:
        """Where the frames are, in their order: the full parts, then the destination (once `stop` put it there)."""
        return [*self.parts, self._pending.output.destination]

    def stop(self) -> None:
        try:
            self._logger.stop()
            if self.parts:         # the last part is a file python-can made after the rotation: the destination's mode
                os.chmod(self._pending.path, self._mode)
                _sync(self._pending.path)
        except BaseException:
            self._pending.keep()
            raise
        self._pending.commit(keep_on_error=True)


def _sync(path) -> None:
    """Flush a closed file's bytes to the disk."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def message_ids(only: Iterable[str], skip: Iterable[str]) -> Optional[frozenset[int]]:
    """The frame ids `--can-only` and `--can-skip` leave (None: every frame); ValueError naming a message that
    protocol/hal.dbc does not have, and the ones it has."""
    from protocol.hal import default_codec
    by_name = {m.name: m.frame_id for m in default_codec().database.messages}
    only, skip = [n.strip() for n in only if n.strip()], [n.strip() for n in skip if n.strip()]
    for option, names in (("--can-only", only), ("--can-skip", skip)):
        unknown = [n for n in names if n not in by_name]
        if unknown:
            raise ValueError(f"{option} {unknown[0]}: no such message in protocol/hal.dbc; one of "
                             f"{', '.join(sorted(by_name))}")
    if not only and not skip:
        return None
    kept = set(by_name[n] for n in only) if only else set(by_name.values())
    return frozenset(kept - {by_name[n] for n in skip})
