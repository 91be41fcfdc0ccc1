"""Small captures read whole, for tests that look at every frame (the tools themselves read captures as streams)."""
from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Callable, Optional

from host_tools.sessions.capture import DIRECTION_FLAG, WORLD, CapturedFrame, SessionCapture, SessionInfo, WorldEvent
from host_tools.sessions.decode import SessionDecoder
from host_tools.sessions.pcapng import LINKTYPE_USER1, Packet, PcapngReader, PcapngWriter


def read_capture(path: Path) -> tuple[SessionCapture, list[CapturedFrame], list[WorldEvent]]:
    """The capture (its description, and `error` once read), its frames and its world events."""
    with SessionCapture.open(path) as capture:
        items = list(capture.items())
    return (capture, [i for i in items if isinstance(i, CapturedFrame)],
            [i for i in items if isinstance(i, WorldEvent)])


def read_frames(path: Path) -> list[CapturedFrame]:
    return read_capture(path)[1]


def read_packets(data: bytes) -> tuple[PcapngReader, list[Packet]]:
    """A pcapng file's bytes read: the reader (its comment, interfaces, `error`) and every packet."""
    reader = PcapngReader(io.BytesIO(data))
    return reader, list(reader.packets())


def copy_capture(source: Path, target: Path, *, world_events: bool = True,
                 more_events: tuple[tuple[float, dict], ...] = (), info: Optional[SessionInfo] = None,
                 keep: Callable[[str], bool] = lambda name: True) -> None:
    """`source` written again to `target`, frame for frame, in the same order: with another description (`info`),
    only the frames whose message `keep(name)` keeps, without its world events (`world_events=False`), or with
    `more_events` (time, event) at the end."""
    with SessionCapture.open(source) as capture:
        items = list(capture.items())
    decoder = SessionDecoder(None)
    with open(target, "wb") as out:
        writer = PcapngWriter(out, comment=(info or capture.info).to_comment())
        links = {name: writer.add_interface(name)
                 for name in dict.fromkeys(i.link for i in items if isinstance(i, CapturedFrame))}
        world = writer.add_interface(WORLD, "", LINKTYPE_USER1)
        for item in items:
            if isinstance(item, CapturedFrame):
                if keep(decoder.decode(item.data, item.time_s, item.link, item.direction, item.original_length).name):
                    writer.write_packet(links[item.link], item.time_s, item.data, DIRECTION_FLAG[item.direction],
                                        item.comment, item.original_length)
            elif world_events:
                writer.write_packet(world, item.time_s, json.dumps(item.event, sort_keys=True).encode())
        for time_s, event in more_events:
            writer.write_packet(world, time_s, json.dumps(event, sort_keys=True).encode())
