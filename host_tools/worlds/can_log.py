"""The one-process world's HAL bus, written to a file by python-can's own `Logger` (`aspod sim --can-log`).

The two nodes of a one-process world meet on a private in-process bus that no outside tool can
join (host_tools/worlds/local_bus.py), and hand each other values rather than bytes. This
writes every frame either node sends as the `can.Message` real CAN would carry (a value frame
packed now, `ValueFrame.data`), stamped with the world's time, through `can.Logger`: the file's
suffix chooses the format (.blf, .asc, .log, .csv, .trc, .txt), and `cantools decode`,
`python -m can.viewer`, `python -m can.player` and `cantools plot` read it with
`protocol/hal.dbc`.

The log is written to a temporary file with the same suffix beside it and put in place by
`stop` (host_tools/outputs.py), so a run that is killed leaves the destination as it was.
"""
from __future__ import annotations

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
    """Logs what `buses` send from now on; `stop()` closes the file and puts it in place."""

    def __init__(self, output: Output, clock: Clock, buses: dict[str, can.BusABC]) -> None:
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

        def logged_send(msg, timeout=None):
            result = send(msg, timeout)        # a send the bus refuses raises before it is logged
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
