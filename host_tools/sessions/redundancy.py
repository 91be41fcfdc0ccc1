"""Several links carrying one session: every frame is sent on all of them, and the receiving end keeps the first copy.

The report asks for redundancy in space: a radio modem that fades with sunspots and a photonic link that
needs line of sight. Here both ends send every frame on every link (`RedundantPort` at the controller,
`client.lines.RedundantLines` at the host), and `FrameMerger` joins what arrives: each link's bytes are cut
into frames on their own (so two links' bytes never interleave inside a frame), and a frame already taken
from another link in the last `MEMORY` frames is dropped as a copy. Whatever one link loses, the other
carries, with no switch-over to decide and no time lost deciding it.

The merger only ever drops exact copies of a frame it has just passed on. Everything else goes to the link
layer, which checks it as always: a damaged copy fails its CRC there, and an attacker's replay of an old
frame (beyond the merger's memory or not) fails the session's counter check (protocol/auth.py).
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Optional

from host_tools.sessions.segments import SegmentCutter

MEMORY = 512           # frames remembered as already taken (a few seconds of traffic at 115200 baud)
QUIET_S = 3.0          # a path that has carried nothing for this long is shown as silent


@dataclass
class PathHealth:
    """One link as the merger saw it."""
    name: str
    frames: int = 0            # complete frames received on it
    first: int = 0             # ... of which it was the first to bring (passed on)
    copies: int = 0            # ... of which another path had brought already (dropped)
    bytes: int = 0
    overlong: int = 0          # runs longer than any frame, dropped
    last_frame_s: Optional[float] = None

    def describe(self, now: float) -> str:
        if self.last_frame_s is None:
            heard = "nothing heard yet"
        else:
            age = now - self.last_frame_s
            heard = f"last frame {age:.1f} s ago" + (" (SILENT)" if age > QUIET_S else "")
        return (f"{self.name}: {self.frames} frames in ({self.first} first, {self.copies} copies dropped), "
                f"{self.bytes} B; {heard}")


class FrameMerger:
    """Joins the frames of several paths: `feed(path, data, now)` returns the bytes of frames not seen before."""

    def __init__(self, paths: list[str]) -> None:
        self.paths = {name: PathHealth(name) for name in paths}
        self._cutters = {name: SegmentCutter() for name in paths}
        self._seen: OrderedDict[bytes, None] = OrderedDict()

    def reset(self, path: str) -> None:
        """Forget a path's unfinished frame (its peer changed: what it left is not the new peer's)."""
        self._cutters[path].reset()

    def feed(self, path: str, data: bytes, now: float) -> bytes:
        health = self.paths[path]
        health.bytes += len(data)
        out = bytearray()
        for segment, length in self._cutters[path].feed(data):
            if length != len(segment):          # no frame is this long: dropped
                health.overlong += 1
            else:
                out += self._take(path, segment, now)
        return bytes(out)

    def _take(self, path: str, segment: bytes, now: float) -> bytes:
        health = self.paths[path]
        health.frames += 1
        health.last_frame_s = now
        if segment in self._seen:
            health.copies += 1
            self._seen.move_to_end(segment)
            return b""
        self._seen[segment] = None
        if len(self._seen) > MEMORY:
            self._seen.popitem(last=False)
        health.first += 1
        return b"\x00" + segment + b"\x00"

    def report(self, now: float) -> list[str]:
        return [health.describe(now) for health in self.paths.values()]
