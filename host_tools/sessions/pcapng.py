"""pcapng, the capture format Wireshark, tshark and capinfos open: the few blocks a session needs.

A file is a Section Header Block, an Interface Description Block per link, then an Enhanced
Packet Block per captured frame (draft-ietf-opsawg-pcapng, sections 4.1, 4.2 and 4.3). Written
little-endian with nanosecond timestamps (`if_tsresol` 9). Each packet's direction is its
`epb_flags` option (bits 0-1: 1 inbound, 2 outbound), which Wireshark shows as
`frame.packet_flags_direction`; a packet may carry a comment (`opt_comment`), as the section does.

`PcapngReader` reads files of either byte order and skips block types it does not know. Bad input
never raises out of it: reading stops at the first block that does not parse, and the reader
keeps what came before it and says where and why it stopped (`error`, with the byte `offset`).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Iterator, Optional

from protocol.files import MIB, read_bounded

SHB, IDB, EPB = 0x0A0D0D0A, 0x00000001, 0x00000006
BYTE_ORDER_MAGIC = 0x1A2B3C4D
OPT_END, OPT_COMMENT = 0, 1
SHB_USERAPPL = 4
IF_NAME, IF_DESCRIPTION, IF_TSRESOL = 2, 3, 9
EPB_FLAGS = 2
LINKTYPE_USER0 = 147          # "reserved for private use" (tcpdump.org link-layer types): our frames
LINKTYPE_USER1 = 148          # the same, for a session's world events (JSON)
NANOSECONDS = 9
# if_tsresol (draft-ietf-opsawg-pcapng, section 4.2, "if_tsresol": one byte; MSB 0: the resolution is 10**-value
# s, MSB 1: 2**-value s; absent: 10**-6). Writers use 6 (libpcap's microseconds) or 9 (nanoseconds); 12, the
# picoseconds of the finest capture hardware, is the finest read: there a 64-bit count still spans 213 days,
# beyond it a count that cannot even hold a day (10**-15: 5 hours) says the timestamps mean nothing.
MAX_TSRESOL_EXP = 12

INBOUND, OUTBOUND = 1, 2      # epb_flags direction bits
MAX_BLOCK = 1 << 20           # no block of ours comes near this; a larger length field is a broken file
# The largest capture file read (`files.read_bounded`), far above what a session records (a frame is tens of
# bytes plus 32 of pcapng; the demo's 3,220 frames make a few hundred KiB); anything larger, or not a regular
# file (a FIFO, /dev/zero), is refused with `InputFileError`: never read until memory runs out, nor waited on.
MAX_CAPTURE_BYTES = 256 * MIB


class CaptureError(ValueError):
    """A capture that does not parse: `offset` is the byte where the broken block starts."""

    def __init__(self, offset: int, reason: str) -> None:
        super().__init__(f"at byte {offset}: {reason}")
        self.offset = offset
        self.reason = reason


@dataclass
class Interface:
    linktype: int
    name: str = ""
    description: str = ""
    tsresol_exp: int = 6       # 10**-6 s unless if_tsresol says otherwise (base 10 only, as we write)


@dataclass
class Packet:
    """One Enhanced Packet Block: which interface, when (s since the epoch), its bytes and options."""

    interface: int
    time_s: float
    data: bytes
    original_length: int
    direction: int = 0         # 0 unknown, INBOUND, OUTBOUND
    comment: str = ""
    offset: int = 0            # where its block starts in the file


def _options(items: list[tuple[int, bytes]]) -> bytes:
    out = bytearray()
    for code, value in items:
        out += struct.pack("<HH", code, len(value)) + value + b"\x00" * (-len(value) % 4)
    if items:
        out += struct.pack("<HH", OPT_END, 0)
    return bytes(out)


def _block(kind: int, body: bytes) -> bytes:
    body += b"\x00" * (-len(body) % 4)
    total = len(body) + 12
    return struct.pack("<II", kind, total) + body + struct.pack("<I", total)


class PcapngWriter:
    """Writes one section to `stream`: its comment (a string) and interfaces first, then packets."""

    def __init__(self, stream: BinaryIO, comment: str = "", application: str = "") -> None:
        self._stream = stream
        options = []
        if comment:
            options.append((OPT_COMMENT, comment.encode()))
        if application:
            options.append((SHB_USERAPPL, application.encode()))
        body = struct.pack("<IHHq", BYTE_ORDER_MAGIC, 1, 0, -1) + _options(options)
        stream.write(_block(SHB, body))
        self.interfaces = 0

    def add_interface(self, name: str, description: str = "", linktype: int = LINKTYPE_USER0) -> int:
        """Declare an interface; returns its id for `write_packet`."""
        options = [(IF_NAME, name.encode()), (IF_TSRESOL, bytes([NANOSECONDS]))]
        if description:
            options.append((IF_DESCRIPTION, description.encode()))
        self._stream.write(_block(IDB, struct.pack("<HHI", linktype, 0, 0) + _options(options)))
        self.interfaces += 1
        return self.interfaces - 1

    def write_packet(self, interface: int, time_s: float, data: bytes, direction: int = 0,
                     comment: str = "", original_length: Optional[int] = None) -> None:
        if not 0 <= interface < self.interfaces:
            raise ValueError(f"interface {interface} was not declared")
        whole = math.floor(max(0.0, time_s))      # split first: a float epoch times 1e9 would lose the nanoseconds
        ticks = whole * 10 ** 9 + round((max(0.0, time_s) - whole) * 1e9)
        options = []
        if direction:
            options.append((EPB_FLAGS, struct.pack("<I", direction)))
        if comment:
            options.append((OPT_COMMENT, comment.encode()))
        head = struct.pack("<IIIII", interface, ticks >> 32, ticks & 0xFFFFFFFF, len(data),
                           len(data) if original_length is None else original_length)
        self._stream.write(_block(EPB, head + data + b"\x00" * (-len(data) % 4) + _options(options)))

    def flush(self) -> None:
        self._stream.flush()


@dataclass
class PcapngReader:
    """Everything in a file that parses: its comment, interfaces and packets, and where it broke."""

    comment: str = ""
    application: str = ""
    interfaces: list[Interface] = field(default_factory=list)
    packets: list[Packet] = field(default_factory=list)
    error: Optional[CaptureError] = None
    size: int = 0

    @classmethod
    def read(cls, path: Path) -> "PcapngReader":
        """Raises `files.InputFileError` (a ValueError) for a file that is missing, unreadable, not a regular
        file or larger than MAX_CAPTURE_BYTES."""
        return cls.parse(read_bounded(path, MAX_CAPTURE_BYTES))

    @classmethod
    def parse(cls, data: bytes) -> "PcapngReader":
        reader = cls()
        reader.size = len(data)
        try:
            for _ in reader._blocks(data):
                pass
        except CaptureError as exc:
            reader.error = exc
        return reader

    def _blocks(self, data: bytes) -> Iterator[None]:
        offset, order = 0, None
        if len(data) < 12:
            raise CaptureError(0, f"{len(data)} bytes is too short for a pcapng file")
        while offset < len(data):
            if len(data) - offset < 12:
                raise CaptureError(offset, f"{len(data) - offset} bytes after the last block: truncated")
            kind = struct.unpack_from("<I", data, offset)[0]
            if kind == SHB:
                magic = data[offset + 8:offset + 12]
                if magic == b"\x4d\x3c\x2b\x1a":
                    order = "<"
                elif magic == b"\x1a\x2b\x3c\x4d":
                    order = ">"
                else:
                    raise CaptureError(offset, "a section header without pcapng's byte-order magic")
            elif order is None:
                raise CaptureError(offset, "not a pcapng file: it does not start with a section header block")
            kind, total = struct.unpack_from(order + "II", data, offset)
            if total < 12 or total % 4 or total > MAX_BLOCK:
                raise CaptureError(offset, f"block length {total} is not a valid pcapng block length")
            if offset + total > len(data):
                raise CaptureError(offset, f"block of {total} bytes runs past the end of the file "
                                           f"({len(data) - offset} left): truncated")
            if struct.unpack_from(order + "I", data, offset + total - 4)[0] != total:
                raise CaptureError(offset, "the block's two length fields differ")
            body = data[offset + 8:offset + total - 4]
            try:
                self._take(kind, body, order, offset)
            except (struct.error, UnicodeDecodeError) as exc:
                raise CaptureError(offset, f"block type {kind:#x} does not parse: {exc}") from None
            offset += total
            yield None

    def _take(self, kind: int, body: bytes, order: str, offset: int) -> None:
        if kind == SHB:
            major = struct.unpack_from(order + "H", body, 4)[0]
            if major != 1:
                raise CaptureError(offset, f"pcapng major version {major}; this reader knows 1")
            for code, value in _read_options(body, 16, order, offset):
                if code == OPT_COMMENT:
                    self.comment = value.decode()
                elif code == SHB_USERAPPL:
                    self.application = value.decode()
        elif kind == IDB:
            interface = Interface(struct.unpack_from(order + "H", body, 0)[0])
            for code, value in _read_options(body, 8, order, offset):
                if code == IF_NAME:
                    interface.name = value.decode()
                elif code == IF_DESCRIPTION:
                    interface.description = value.decode()
                elif code == IF_TSRESOL:
                    if len(value) != 1:
                        raise CaptureError(offset, f"if_tsresol of {len(value)} bytes; the option is one byte")
                    if value[0] & 0x80:
                        raise CaptureError(offset, "if_tsresol in powers of 2 is not supported")
                    if value[0] > MAX_TSRESOL_EXP:
                        raise CaptureError(offset, f"if_tsresol 10^-{value[0]} s: timestamps finer than "
                                                   f"10^-{MAX_TSRESOL_EXP} s (picoseconds) mean nothing")
                    interface.tsresol_exp = value[0]
            self.interfaces.append(interface)
        elif kind == EPB:
            iface, high, low, captured, original = struct.unpack_from(order + "IIIII", body, 0)
            if iface >= len(self.interfaces):
                raise CaptureError(offset, f"packet on interface {iface}, which was not declared")
            if 20 + captured > len(body):
                raise CaptureError(offset, f"captured length {captured} runs past its block")
            packet = Packet(iface, ((high << 32) | low) / 10 ** self.interfaces[iface].tsresol_exp,
                            body[20:20 + captured], original, offset=offset)
            for code, value in _read_options(body, 20 + captured + (-captured % 4), order, offset):
                if code == EPB_FLAGS and len(value) == 4:
                    packet.direction = struct.unpack(order + "I", value)[0] & 0x3
                elif code == OPT_COMMENT:
                    packet.comment = value.decode()
            self.packets.append(packet)


def _read_options(body: bytes, at: int, order: str, offset: int) -> Iterator[tuple[int, bytes]]:
    while at + 4 <= len(body):
        code, length = struct.unpack_from(order + "HH", body, at)
        if code == OPT_END:
            return
        at += 4
        if at + length > len(body):
            raise CaptureError(offset, f"option {code} of {length} bytes runs past its block")
        yield code, body[at:at + length]
        at += length + (-length % 4)
