"""A session's capture: every frame that crossed a link, both ways, in a pcapng file.

One packet per frame, as it was on the wire: the COBS segment between two 0x00 delimiters, so a
frame that a bit error broke is kept exactly as it came (the decoder says what is wrong with it).
Each link is a pcapng interface named after it ("link", or "radio" and "optical"); the packet's
direction is the host's view: outbound is host -> controller, inbound is controller -> host.
What a bench did to the plant outside the link (`LockstepBench.act`) is kept as world events:
JSON objects on an interface named `world`, link type USER1.

The section comment holds what a reader needs to make sense of the rest, as one line of JSON
after the word `aspod-session`: the format's version, the protocol version and schema hash the
frames were written with, which clock the timestamps come from (`simulated`: seconds since the
world started, on a simulated clock; `paced`: the same, on a world paced to the wall clock, as
`aspod sim` runs; `wall`: the Unix epoch), and the recording tool's settings and seed (what
`aspod replay` needs to build the same world).
"""
from __future__ import annotations

import json
import math
import re
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Iterator, Optional, Union

from protocol.files import InputFileError, open_input
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.schema import Direction
from timebase import RealClock
from host_tools import strict_json
from host_tools.outputs import Kind, Output, Pending, begins, unclaimed
from host_tools.sessions.segments import SegmentCutter
from host_tools.sessions.pcapng import INBOUND, LINKTYPE_USER1, OUTBOUND, SHB, CaptureError, PcapngReader, PcapngWriter

FORMAT_VERSION = 1
SEED_MAX = 2**32 - 1     # seeds of the plant's noise and the link's nonces (the command line's --seed): 0 .. 4294967295
MARK = "aspod-session "
# A recording's settings (the plant, every controller parameter, an impairment's or a fault's description, ...) are
# a few dozen short entries (aspod sim's: 73 parameters, 1.6 kB in all). Far above that they are refused, not built
# into a world: entries of any one object or list, and characters of any one string or key (the tool's name too).
MAX_SETTING_ENTRIES = 1024
MAX_SETTING_CHARS = 1024
DIRECTION_FLAG = {Direction.TO_CONTROLLER: OUTBOUND, Direction.TO_HOST: INBOUND}
FLAG_DIRECTION = {flag: direction for direction, flag in DIRECTION_FLAG.items()}
CLOCKS = ("simulated", "paced", "wall")
WORLD = "world"       # the interface of world events: JSON objects, link type USER1 (Wireshark shows them as data)
# What --record and replay's --output write, and may write over: a pcapng file, which begins with its Section Header
# Block's type (the same four bytes in either byte order); ours or any other tool's.
CAPTURE = Kind("a pcapng capture", begins(SHB.to_bytes(4, "little")))


@dataclass
class SessionInfo:
    """What the section comment says about a capture."""

    clock: str = "wall"
    tool: str = ""
    settings: dict[str, Any] = field(default_factory=dict)
    seed: Optional[int] = None
    protocol_version: int = PROTOCOL_VERSION
    schema_hash: int = SCHEMA.hash

    def to_comment(self) -> str:
        return MARK + json.dumps({"format": FORMAT_VERSION, "protocol_version": self.protocol_version,
                                  "schema_hash": f"{self.schema_hash:016x}", "clock": self.clock,
                                  "tool": self.tool, "seed": self.seed, "settings": self.settings},
                                 sort_keys=True)

    @classmethod
    def from_comment(cls, comment: str) -> "SessionInfo":
        """Raises ValueError with the reason (naming the field) when the comment is not an aspod session's.

        Each field is checked by type and by the bounds the command line applies (the seed as --seed), since
        `aspod replay` builds a world from them."""
        if not comment.startswith(MARK):
            raise ValueError("the capture's section comment does not describe an aspod session")
        doc = _json_object(comment[len(MARK):], "the session description")
        if doc.get("format") != FORMAT_VERSION or isinstance(doc.get("format"), bool):
            raise ValueError(f"capture format {_short(doc.get('format'))}; this version reads {FORMAT_VERSION}")
        for name in ("clock", "protocol_version", "schema_hash"):
            if name not in doc:
                raise ValueError(f"the session description does not parse: it has no {name!r}")
        clock, tool, settings = doc["clock"], doc.get("tool", ""), doc.get("settings")
        version, schema_hash, seed = doc["protocol_version"], doc["schema_hash"], doc.get("seed")
        if not isinstance(clock, str) or clock not in CLOCKS:
            raise ValueError(f"clock {_short(clock)} is not one of {', '.join(CLOCKS)}")
        if not isinstance(tool, str):
            raise ValueError(f"tool {_short(tool)} is not a string")
        if settings is not None and not isinstance(settings, dict):
            raise ValueError(f"settings {_short(settings)} is not a JSON object")
        _check_sizes(tool, "tool")
        _check_sizes(settings, "settings")
        if isinstance(version, bool) or not isinstance(version, int) or not 0 <= version <= 0xFFFF:
            raise ValueError(f"protocol_version {_short(version)} is not a whole number in 0..65535")
        if not isinstance(schema_hash, str) or not re.fullmatch(r"[0-9a-fA-F]{1,16}", schema_hash):
            raise ValueError(f"schema_hash {_short(schema_hash)} is not a 64-bit hexadecimal number")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= SEED_MAX):
            raise ValueError(f"seed {_short(seed)} is not a whole number in 0..{SEED_MAX} (as --seed)")
        return cls(clock=clock, tool=tool, settings=dict(settings or {}), seed=seed, protocol_version=version,
                   schema_hash=int(schema_hash, 16))

    @property
    def same_schema(self) -> bool:
        return self.protocol_version == PROTOCOL_VERSION and self.schema_hash == SCHEMA.hash

    def schema_mismatch(self) -> str:
        """Empty when this build speaks the capture's protocol, else why not."""
        if self.same_schema:
            return ""
        return (f"the capture was written with protocol v{self.protocol_version}, schema {self.schema_hash:016x}; "
                f"this build speaks v{PROTOCOL_VERSION}, schema {SCHEMA.hash:016x}: messages may decode wrongly")


class CaptureWriter:
    """Writes a session's capture as it happens: `write(link, direction, data, time_s)` for every read or write.

    Bytes are cut into frames per link and direction (`SegmentCutter`); each frame is written with
    the time its closing delimiter was seen. The file is flushed after every frame, so a session
    that ends abruptly leaves a capture that reads up to its last frame.

    Made by `create`, it writes a temporary file beside its destination (host_tools/outputs.py):
    `close` puts the capture in place, whole; `discard` leaves the destination as it was. A
    capture that could not be written (a full disk: `write` raised) is not put in place by
    `close`: its temporary is left, holding the frames before the failure, at `partial`.
    """

    def __init__(self, stream: BinaryIO, info: SessionInfo, links: tuple[str, ...] = ("link",),
                 pending: Optional[Pending] = None, started_s: Optional[float] = None) -> None:
        self._pending = pending
        self._stream = stream
        self.failed = False
        # the tools name themselves `aspod sim`, ...: not `aspod aspod sim` (a bench's `vectors` gets the prefix)
        application = info.tool if info.tool.startswith("aspod") else f"aspod {info.tool}".strip()
        self._pcap = PcapngWriter(stream, comment=info.to_comment(), application=application)
        # On a world's clock (simulated, paced) the times written are the session's own, from 0: the wall-clock second
        # it began (now, unless told) is each interface's if_tsoffset, so Wireshark shows the day and hour (1970
        # without it) while the times stay the session's. On the wall clock they are Unix time already.
        self._started_s = 0 if info.clock == "wall" else math.floor(RealClock.wall_time() if started_s is None else started_s)
        self._links = {name: self._pcap.add_interface(name, f"ASPOD link {name!r}", tsoffset_s=self._started_s)
                       for name in links}
        self._taps = {(name, d): SegmentCutter() for name in links for d in DIRECTION_FLAG}
        self.frames = 0
        self._world: Optional[int] = None
        stream.flush()              # a capture of no frame yet is a capture too: killed now, it reads

    @classmethod
    def create(cls, output: Union[Output, Path], info: SessionInfo, links: tuple[str, ...] = ("link",),
               started_s: Optional[float] = None) -> "CaptureWriter":
        """A capture into `output` (claimed by the command's settings; a plain path is written the same way)."""
        pending = unclaimed(output, CAPTURE).open()
        try:
            return cls(pending.file, info, links, pending, started_s)
        except BaseException:
            pending.discard()
            raise

    @property
    def partial(self) -> Optional[Path]:
        """The temporary file the capture is written to until `close` (None: a stream given by the caller)."""
        return None if self._pending is None else self._pending.path

    def write(self, link: str, direction: Direction, data: bytes, time_s: float, comment: str = "") -> None:
        if not data:
            return
        iface = self._links[link]
        with self._failing():
            for segment, length in self._taps[(link, direction)].feed(data):
                self._pcap.write_packet(iface, time_s, segment, DIRECTION_FLAG[direction], comment, length)
                self.frames += 1
            self._stream.flush()

    def note(self, event: dict[str, Any], time_s: float) -> None:
        """A world event (something done to the plant outside the link), as JSON on the `world` interface."""
        with self._failing():
            if self._world is None:
                self._world = self._pcap.add_interface(WORLD, "events in the world outside the link", LINKTYPE_USER1,
                                                       tsoffset_s=self._started_s)
            self._pcap.write_packet(self._world, time_s, json.dumps(event, sort_keys=True).encode())
            self._stream.flush()

    @contextmanager
    def _failing(self):
        try:
            yield
        except OSError:
            self.failed = True
            raise

    def close(self) -> None:
        """The capture is complete: into its place. Failed, or if it cannot be put in place (OSError), its
        temporary is left at `partial` with every frame written."""
        if self._pending is None:
            self._stream.close()
        elif self.failed:
            self._pending.keep()
        else:
            self._pending.commit(keep_on_error=True)

    def discard(self) -> None:
        """The run failed before its capture meant anything: the temporary removed, the destination as it was."""
        if self._pending is None:
            self._stream.close()
        else:
            self._pending.discard()


@dataclass
class CapturedFrame:
    """One packet of a session capture: when, on which link, which way, and its wire bytes."""

    time_s: float
    link: str
    direction: Direction
    data: bytes
    original_length: int
    comment: str
    offset: int
    note: str = ""          # its block was larger than a reader holds: what was kept (`Packet.note`)
    started_s: int = 0      # its interface's if_tsoffset: on a world's clock, the wall-clock second the session began

    @property
    def truncated(self) -> bool:
        return self.original_length != len(self.data)


@dataclass
class WorldEvent:
    """One world event of a capture: when, the JSON object, where; `error` says why one does not parse (then
    `event` is None). `index` is its number among the capture's world events, from 0."""

    time_s: float
    event: Optional[dict]
    offset: int
    index: int
    error: str = ""


class SessionCapture:
    """A session capture read as a stream: its description at once, then its frames and world events one at a
    time, in file order, holding one block at a time whatever the file's size (`PcapngReader`).

    Each `items()` (or `frames()`) reads the file again from its start. Bad content never raises: `error` says
    where and why the last reading stopped, `warnings` what is odd about the capture as a whole.
    """

    def __init__(self, stream: BinaryIO) -> None:
        self._stream = stream
        header = PcapngReader(stream)
        header.read_section_header()
        self.size = header.size
        self.error: Optional[CaptureError] = header.error
        self.warnings: list[str] = []
        self.info: Optional[SessionInfo] = None
        self.info_error = ""          # why the section comment does not describe a session (info is then None)
        if header.error is None:
            try:
                self.info = SessionInfo.from_comment(header.comment)
            except ValueError as exc:
                self.info_error = str(exc)
                self.warnings.append(f"{exc}; decoding it as this build's protocol")
            else:
                if mismatch := self.info.schema_mismatch():
                    self.warnings.append(mismatch)

    @classmethod
    def open(cls, path: Path) -> "SessionCapture":
        """Never raises for bad content; a file that is missing, unreadable or not a regular file (a FIFO, a
        device, a directory) raises `files.InputFileError`. Close it (or use it in a `with`)."""
        stream = open_input(path)
        try:
            return cls(stream)
        except OSError as exc:
            stream.close()
            raise InputFileError(path, f"cannot read it: {exc.strerror or exc}") from None

    def close(self) -> None:
        self._stream.close()

    def __enter__(self) -> "SessionCapture":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def items(self) -> Iterator[Union[CapturedFrame, WorldEvent]]:
        """Every frame and world event, in file order, up to the end or the block where the file breaks."""
        pcap = PcapngReader(self._stream)
        world_events = 0
        undirected = False
        for p in pcap.packets():
            interface = pcap.interfaces[p.interface]
            if interface.name == WORLD and interface.linktype == LINKTYPE_USER1:
                try:
                    yield WorldEvent(p.time_s, _json_object(p.data.decode(), "it"), p.offset, world_events)
                except ValueError as exc:
                    yield WorldEvent(p.time_s, None, p.offset, world_events,
                                     f"world event {world_events} (at byte {p.offset}) does not parse ({exc})")
                world_events += 1
                continue
            if p.direction not in FLAG_DIRECTION and not undirected:
                undirected = True
                said = f"packet at byte {p.offset} has no direction; taken as controller -> host"
                if said not in self.warnings:
                    self.warnings.append(said)
            yield CapturedFrame(p.time_s, interface.name or f"if{p.interface}",
                                FLAG_DIRECTION.get(p.direction, Direction.TO_HOST), p.data, p.original_length,
                                p.comment, p.offset, p.note, interface.tsoffset_s)
        self.error = pcap.error

    def frames(self) -> Iterator[CapturedFrame]:
        """The frames of `items()`, without the world events."""
        return (item for item in self.items() if isinstance(item, CapturedFrame))


def describe_world_event(event: dict) -> str:
    """A world event as one line of `aspod log`: `inject(jam:j2)`, `control {"op": ...}`; any JSON object."""
    if "control" in event:
        return "control " + _short(event["control"])
    def said(value: Any) -> str:
        return value[:60] if isinstance(value, str) else _short(value)
    args = event.get("args", [])
    shown = ", ".join(map(said, args)) if isinstance(args, list) else _short(args)
    return f"{said(event.get('action'))}({shown})"


def _short(value: Any) -> str:
    """A value for an error message: repr, cut short."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_sizes(value: Any, where: str) -> None:
    """ValueError naming the place in `value` (a JSON value) where an object or list holds more than
    MAX_SETTING_ENTRIES entries, or a string or key more than MAX_SETTING_CHARS characters."""
    if isinstance(value, str):
        if len(value) > MAX_SETTING_CHARS:
            raise ValueError(f"{where} is a string of {len(value)} characters; at most {MAX_SETTING_CHARS}")
    elif isinstance(value, (dict, list)):
        if len(value) > MAX_SETTING_ENTRIES:
            raise ValueError(f"{where} holds {len(value)} entries; at most {MAX_SETTING_ENTRIES}")
        for key, item in (value.items() if isinstance(value, dict) else enumerate(value)):
            _check_sizes(key, f"a key in {where}")
            _check_sizes(item, f"{where}[{_short(key)}]")


def _json_object(text: str, what: str) -> dict:
    """`text` as a JSON object, read strictly (`strict_json.loads`); ValueError naming `what` and why."""
    try:
        doc = strict_json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{what} does not parse: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{what} is not a JSON object: {_short(doc)}")
    return doc
