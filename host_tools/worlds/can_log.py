"""The one-process world's HAL bus, written to a file by python-can's own `Logger` (`aspod sim --can-log`).

The two nodes of a one-process world meet on a private in-process bus that no outside tool can
join (host_tools/worlds/local_bus.py), and hand each other values rather than bytes. This
writes every frame either node sends as the `can.Message` real CAN would carry (a value frame
packed now, `ValueFrame.data`), stamped with the world's time, through `can.Logger`: the file's
suffix chooses the format (.blf, .asc, .log, .csv, .trc, .txt), and `cantools decode`,
`python -m can.viewer`, `python -m can.player` and `cantools plot` read it with
`protocol/hal.dbc`. `--can-only`/`--can-skip` keep some messages only (`message_ids`). Most of the bus
is the 1 kHz MOTOR_CMD, MOTOR_FB and PLANT_SYNC: measured, 20 s of `aspod sim` made a 4.5 MB candump
.log and a 0.49 MB .blf (zlib-compressed, 9.3 times smaller), so a long run is best logged as .blf, or
without those three.

The log is written to a temporary file with the same suffix beside it and put in place by
`stop` (host_tools/outputs.py), so a run that is killed leaves the destination as it was.
"""
from __future__ import annotations

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


class HalBusLog:
    """Logs what `buses` send from now on (of `ids` only, if given: a filter by message); `stop()` closes the file
    and puts it in place."""

    def __init__(self, output: Output, clock: Clock, buses: dict[str, can.BusABC],
                 ids: Optional[frozenset[int]] = None) -> None:
        self._ids = ids
        self._pending = output.open()
        try:
            self._logger = can.Logger(str(self._pending.path))     # the temporary's suffix picks the format
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

    def stop(self) -> None:
        try:
            self._logger.stop()
        except BaseException:
            self._pending.keep()
            raise
        self._pending.commit(keep_on_error=True)


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
