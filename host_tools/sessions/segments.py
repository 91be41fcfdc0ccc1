"""A byte stream cut into wire segments (what lies between two 0x00 delimiters), the one cutter of the sessions
tools: the capture (`CaptureWriter`), the impaired line (`ImpairedLine`) and the redundant links' merger
(`FrameMerger`) all see frames as it cuts them. (The link's own receiver, protocol/framing.py `FrameReceiver`,
cuts and decodes in one pass on the hot path.)"""
from __future__ import annotations

from protocol.framing import MAX_ENCODED


class SegmentCutter:
    """Cuts one direction's byte stream into wire segments, as a receiver would.

    Holds at most one frame's worth between feeds. A run of bytes longer than any frame is
    handed on cut to that length, flagged `overlong` with its true length, and the rest of it
    up to the next delimiter is only counted.
    """

    def __init__(self) -> None:
        self._pending = bytearray()
        self._overlong = 0         # > 0: inside an over-long segment, this many bytes so far

    def feed(self, data: bytes) -> list[tuple[bytes, int]]:
        """The segments `data` completes: (captured bytes, true length)."""
        out: list[tuple[bytes, int]] = []
        start = 0
        while True:
            end = data.find(b"\x00", start)
            piece = data[start:] if end < 0 else data[start:end]
            if self._overlong:
                self._overlong += len(piece)
            elif len(self._pending) + len(piece) > MAX_ENCODED:
                self._overlong = len(self._pending) + len(piece)
                self._pending += piece[:MAX_ENCODED - len(self._pending)]
            else:
                self._pending += piece
            if end < 0:
                return out
            if self._pending:
                out.append((bytes(self._pending), self._overlong or len(self._pending)))
            self._pending.clear()
            self._overlong = 0
            start = end + 1

    def reset(self) -> None:
        """Forget the unfinished segment (the stream's source changed: what it left is not the new one's)."""
        self._pending.clear()
        self._overlong = 0
