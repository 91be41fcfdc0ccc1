"""pcapng, the capture format Wireshark, tshark and capinfos open: the few blocks a session needs.

A file is a Section Header Block, an Interface Description Block per link, then an Enhanced
Packet Block per captured frame (draft-ietf-opsawg-pcapng, sections 4.1, 4.2 and 4.3). Written
little-endian with nanosecond timestamps (`if_tsresol` 9). Each packet's direction is its
`epb_flags` option (bits 0-1: 1 inbound, 2 outbound), which Wireshark shows as
`frame.packet_flags_direction`; a packet may carry a comment (`opt_comment`), as the section does.

`PcapngReader` reads a file of either byte order as a stream, one block at a time, and skips block types it
does not know. Bad input never raises out of it: reading stops at the first block that does not parse, and the
reader has given what came before it and says where and why it stopped (`error`, with the byte `offset`).
"""
from __future__ import annotations

import io
import math
import struct
from dataclasses import dataclass
from typing import BinaryIO, Iterator, Optional

from protocol.files import KIB, MIB, size_text

SHB, IDB, EPB = 0x0A0D0D0A, 0x00000001, 0x00000006
BYTE_ORDER_MAGIC = 0x1A2B3C4D
OPT_END, OPT_COMMENT = 0, 1
SHB_USERAPPL = 4
IF_NAME, IF_DESCRIPTION, IF_TSRESOL, IF_TSOFFSET = 2, 3, 9, 14
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
# A file is read one block at a time, whatever its size. No block of ours comes near MAX_BLOCK (a frame is tens of
# bytes plus 32 of pcapng); a larger one is read only in part: of a packet, its first MAX_KEPT bytes (far more than
# any frame, 1 KiB), and its true length. A section holds at most MAX_INTERFACES interfaces (a session: one a
# link and one for world events), each name and description kept to MAX_NAME_CHARS characters.
MAX_BLOCK = 1 * MIB
MAX_KEPT = 64 * KIB
MAX_INTERFACES = 1024
MAX_NAME_CHARS = 256


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
    tsoffset_s: int = 0        # if_tsoffset: seconds readers like Wireshark add to the times (ours keep them apart)


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
    note: str = ""             # its block was larger than the reader holds: what was kept of it


def nanoseconds(time_s: float) -> int:
    """A time as `PcapngWriter` stamps it: whole nanoseconds, from 0 (a reader gives back `nanoseconds(t) / 1e9`)."""
    whole = math.floor(max(0.0, time_s))      # split first: a float epoch times 1e9 would lose the nanoseconds
    return whole * 10 ** 9 + round((max(0.0, time_s) - whole) * 1e9)


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

    def add_interface(self, name: str, description: str = "", linktype: int = LINKTYPE_USER0,
                      tsoffset_s: int = 0) -> int:
        """Declare an interface; returns its id for `write_packet`. `tsoffset_s`, if not 0, is its if_tsoffset: the
        seconds a reader adds to its packets' times to date them (Wireshark does; `PcapngReader` keeps them apart)."""
        options = [(IF_NAME, name.encode()), (IF_TSRESOL, bytes([NANOSECONDS]))]
        if description:
            options.append((IF_DESCRIPTION, description.encode()))
        if tsoffset_s:
            options.append((IF_TSOFFSET, struct.pack("<q", tsoffset_s)))
        self._stream.write(_block(IDB, struct.pack("<HHI", linktype, 0, 0) + _options(options)))
        self.interfaces += 1
        return self.interfaces - 1

    def write_packet(self, interface: int, time_s: float, data: bytes, direction: int = 0,
                     comment: str = "", original_length: Optional[int] = None) -> None:
        if not 0 <= interface < self.interfaces:
            raise ValueError(f"interface {interface} was not declared")
        ticks = nanoseconds(time_s)
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


class PcapngReader:
    """A pcapng stream read one block at a time: its comment and interfaces as they come, its packets one by one.

    It holds one block at a time, at most MAX_BLOCK bytes, whatever the file's size. A block that declares more
    (a length field may say up to 4 GiB) is never read whole: its two length fields are compared, and an Enhanced
    Packet Block's packet is kept cut to MAX_KEPT bytes with its true length (`Packet.note` says so, with the
    block's offset); a section header or an interface that large breaks the file there, and any other block is
    skipped. Reading stops at the first block that does not parse, and `error` says where and why.
    """

    def __init__(self, stream: BinaryIO) -> None:
        self._stream = stream
        self.comment = ""
        self.application = ""
        self.interfaces: list[Interface] = []     # of the current section (a new section declares its own)
        self.error: Optional[CaptureError] = None
        stream.seek(0, io.SEEK_END)
        self.size = stream.tell()                 # what there was to read when it was opened
        stream.seek(0)
        self._offset = 0                          # where the next block starts
        self._order: Optional[str] = None

    def read_section_header(self) -> None:
        """Read the first block (the section header: its comment and application) unless already read."""
        if self._offset == 0 and self.error is None:
            for _ in self._blocks(only_one=True):
                pass

    def packets(self) -> Iterator[Packet]:
        """Every packet from where reading stands up to the end, or up to the first block that does not parse."""
        return (packet for packet in self._blocks() if packet is not None)

    def _blocks(self, only_one: bool = False) -> Iterator[Optional[Packet]]:
        try:
            while self.error is None and (self._offset < self.size or self._offset == 0):
                yield self._next_block()
                if only_one:
                    return
        except CaptureError as exc:
            self.error = exc
        except OSError as exc:          # the disk, not the content: said the same way, where it happened
            self.error = CaptureError(self._offset, f"cannot read it: {exc.strerror or exc}")

    def _next_block(self) -> Optional[Packet]:
        offset, left = self._offset, self.size - self._offset
        if self.size < 12:
            raise CaptureError(0, f"{self.size} bytes is too short for a pcapng file")
        if left < 12:
            raise CaptureError(offset, f"{left} bytes after the last block: truncated")
        self._stream.seek(offset)
        head = self._read(offset, 12)
        if struct.unpack_from("<I", head)[0] == SHB:
            if head[8:12] == b"\x4d\x3c\x2b\x1a":
                self._order = "<"
            elif head[8:12] == b"\x1a\x2b\x3c\x4d":
                self._order = ">"
            else:
                raise CaptureError(offset, "a section header without pcapng's byte-order magic")
        elif self._order is None:
            raise CaptureError(offset, "not a pcapng file: it does not start with a section header block")
        order = self._order
        kind, total = struct.unpack_from(order + "II", head)
        if total < 12 or total % 4:
            raise CaptureError(offset, f"block length {total} is not a valid pcapng block length")
        if total > left:
            raise CaptureError(offset, f"block of {total} bytes runs past the end of the file ({left} left): "
                                       "truncated")
        if total > MAX_BLOCK:
            packet = self._large_block(kind, total, offset)
        else:
            data = head + self._read(offset, total - 12)
            if struct.unpack_from(order + "I", data, total - 4)[0] != total:
                raise CaptureError(offset, "the block's two length fields differ")
            try:
                packet = self._take(kind, data[8:total - 4], order, offset)
            except (struct.error, UnicodeDecodeError) as exc:
                raise CaptureError(offset, f"block type {kind:#x} does not parse: {exc}") from None
        self._offset = offset + total
        return packet

    def _read(self, offset: int, count: int) -> bytes:
        data = self._stream.read(count)
        if len(data) < count:       # the file was cut short while it was read
            raise CaptureError(offset, "the file ends inside this block: truncated")
        return data

    def _large_block(self, kind: int, total: int, offset: int) -> Optional[Packet]:
        """A block longer than MAX_BLOCK, read only in the parts that are needed (module docstring)."""
        order, said = self._order, f"a block of {total} bytes at byte {offset}, more than the " \
                                   f"{size_text(MAX_BLOCK)} this reader holds at once"
        self._stream.seek(offset + total - 4)
        if struct.unpack(order + "I", self._read(offset, 4))[0] != total:
            raise CaptureError(offset, "the block's two length fields differ")
        if kind in (SHB, IDB):
            what = "a section header" if kind == SHB else "an interface"
            raise CaptureError(offset, f"{said}: {what} this large is not read")
        if kind != EPB:
            return None                                         # skipped, as every block of an unknown type
        self._stream.seek(offset + 8)
        iface, high, low, captured, original = struct.unpack(order + "IIIII", self._read(offset, 20))
        if iface >= len(self.interfaces):
            raise CaptureError(offset, f"packet on interface {iface}, which was not declared")
        if 20 + captured > total - 12:
            raise CaptureError(offset, f"captured length {captured} runs past its block")
        data = self._read(offset, min(captured, MAX_KEPT))
        packet = Packet(iface, ((high << 32) | low) / 10 ** self.interfaces[iface].tsresol_exp, data,
                        max(original, captured), offset=offset,
                        note=f"{said}: its packet of {captured} bytes is kept cut to {len(data)}")
        options_at = 20 + captured + (-captured % 4)
        if total - 12 - options_at <= MAX_BLOCK:
            self._stream.seek(offset + 8 + options_at)
            self._packet_options(packet, self._read(offset, total - 12 - options_at), 0, order, offset)
        else:
            packet.note += ", its options not read"
        return packet

    def _take(self, kind: int, body: bytes, order: str, offset: int) -> Optional[Packet]:
        if kind == SHB:
            major = struct.unpack_from(order + "H", body, 4)[0]
            if major != 1:
                raise CaptureError(offset, f"pcapng major version {major}; this reader knows 1")
            self.interfaces = []                # a section's interfaces are its own, numbered from 0
            for code, value in _read_options(body, 16, order, offset):
                if code == OPT_COMMENT:
                    self.comment = value.decode()
                elif code == SHB_USERAPPL:
                    self.application = value.decode()
        elif kind == IDB:
            if len(self.interfaces) >= MAX_INTERFACES:
                raise CaptureError(offset, f"more than {MAX_INTERFACES} interfaces in one section")
            interface = Interface(struct.unpack_from(order + "H", body, 0)[0])
            for code, value in _read_options(body, 8, order, offset):
                if code == IF_NAME:
                    interface.name = value.decode()[:MAX_NAME_CHARS]
                elif code == IF_DESCRIPTION:
                    interface.description = value.decode()[:MAX_NAME_CHARS]
                elif code == IF_TSRESOL:
                    if len(value) != 1:
                        raise CaptureError(offset, f"if_tsresol of {len(value)} bytes; the option is one byte")
                    if value[0] & 0x80:
                        raise CaptureError(offset, "if_tsresol in powers of 2 is not supported")
                    if value[0] > MAX_TSRESOL_EXP:
                        raise CaptureError(offset, f"if_tsresol 10^-{value[0]} s: timestamps finer than "
                                                   f"10^-{MAX_TSRESOL_EXP} s (picoseconds) mean nothing")
                    interface.tsresol_exp = value[0]
                elif code == IF_TSOFFSET and len(value) == 8:
                    interface.tsoffset_s = struct.unpack(order + "q", value)[0]
            self.interfaces.append(interface)
        elif kind == EPB:
            iface, high, low, captured, original = struct.unpack_from(order + "IIIII", body, 0)
            if iface >= len(self.interfaces):
                raise CaptureError(offset, f"packet on interface {iface}, which was not declared")
            if 20 + captured > len(body):
                raise CaptureError(offset, f"captured length {captured} runs past its block")
            packet = Packet(iface, ((high << 32) | low) / 10 ** self.interfaces[iface].tsresol_exp,
                            body[20:20 + captured], original, offset=offset)
            self._packet_options(packet, body, 20 + captured + (-captured % 4), order, offset)
            return packet
        return None

    @staticmethod
    def _packet_options(packet: Packet, body: bytes, at: int, order: str, offset: int) -> None:
        for code, value in _read_options(body, at, order, offset):
            if code == EPB_FLAGS and len(value) == 4:
                packet.direction = struct.unpack(order + "I", value)[0] & 0x3
            elif code == OPT_COMMENT:
                packet.comment = value.decode()


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
