"""The controller's serial line: the `Port` it reads and writes, and the line's pacing.

A port is a non-blocking byte pipe (`read(max_bytes)`, `write(data) -> int`); the OS ports
(pty, TCP, device, memory) are the host side's, in `host_tools/worlds/ports.py`.

`PacedUart` emulates the wire time of an 8N1 line (10 bits a byte) at the configured
baud in both directions: bytes a host writes in a burst reach the protocol no faster
than the line would carry them, and a frame the controller sends reaches the host
when its last bit would have. A pty ignores the baud rate entirely, so without this
a host would see no line timing at all.
"""
from __future__ import annotations

from typing import Optional, Protocol

from protocol.line import BAUD_RATES, BITS_PER_BYTE   # 8N1: start + 8 data + stop (re-exported: the CLI's --baud)

__all__ = ["BAUD_RATES", "BITS_PER_BYTE", "PacedUart", "Port"]
MAX_PENDING_OUT = 64 * 1024   # bytes held for a host that is not reading before they are dropped
RX_LOOKAHEAD = 4096           # bytes read ahead from the OS while the line delivers them


class Port(Protocol):
    url: str

    def read(self, max_bytes: int) -> bytes: ...
    def write(self, data: bytes) -> int: ...
    def close(self) -> None: ...


class PacedUart:
    """8N1 wire-time emulation over a `Port`, driven by `now`."""

    def __init__(self, port: Port, baud: int = 115200, paced: bool = True) -> None:
        if baud not in BAUD_RATES:
            raise ValueError(f"baud {baud} is not one of {', '.join(map(str, BAUD_RATES))}")
        self.port = port
        self.baud = baud
        self.paced = paced
        self.byte_time_s = BITS_PER_BYTE / baud
        self._rx_buf = bytearray()                  # read from the OS, not yet delivered by the line
        self._rx_generation = getattr(port, "generation", 0)   # the port's client the bytes came from
        self.discarded_rx_bytes = 0                 # held back for a client that left or was replaced
        self._rx_head_s = 0.0                       # when the last delivered byte finished arriving
        self._tx_wire_s = 0.0                       # when the transmitter is next idle
        self._in_flight: list[tuple[float, bytes]] = []   # frames on the wire: (done time, bytes)
        self._pending_out = bytearray()             # done on the wire, not yet taken by the OS
        self.dropped_out_bytes = 0

    def wire_time_s(self, nbytes: int) -> float:
        return nbytes * self.byte_time_s

    # ---- receive ----
    def receive(self, now: float, max_bytes: int = 4096) -> bytes:
        """Bytes the line has delivered by `now`.

        Reads up to `RX_LOOKAHEAD` bytes ahead from the OS (the rest waits there, as
        it would in the sender's UART) and releases them one byte time apart. Bytes
        that find the line idle start arriving at `now`, so the emulated line is
        never faster than the wire.
        """
        if not self.paced:
            return self.port.read(max_bytes)
        buf = self._rx_buf
        if len(buf) < RX_LOOKAHEAD:
            data = self.port.read(RX_LOOKAHEAD - len(buf))
            generation = getattr(self.port, "generation", 0)
            if generation != self._rx_generation:    # another client now: what the old one left is not its
                self._rx_generation = generation
                self.discarded_rx_bytes += len(buf)
                buf.clear()
            if data:
                if not buf and self._rx_head_s < now:
                    self._rx_head_s = now
                buf += data
        if not buf:
            return b""
        count = min(len(buf), max_bytes, int((now - self._rx_head_s) / self.byte_time_s + 1e-9))
        if count <= 0:
            return b""
        out = bytes(buf[:count])
        del buf[:count]
        self._rx_head_s += count * self.byte_time_s
        return out

    @property
    def rx_busy(self) -> bool:
        """A frame is arriving: bytes are on the line that have not all been delivered."""
        return bool(self._rx_buf)

    def next_rx_deadline(self) -> Optional[float]:
        """When the next delimiter (a frame boundary) held back will have arrived."""
        if not self._rx_buf:
            return None
        end = self._rx_buf.find(0)
        if end < 0:
            end = len(self._rx_buf) - 1
        return self._rx_head_s + (end + 1) * self.byte_time_s

    # ---- transmit ----
    def tx_idle(self, now: float) -> bool:
        return not self.paced or self._tx_wire_s <= now

    def transmit(self, frame: bytes, now: float) -> None:
        """Put `frame` on the wire; it reaches the port when its last byte would have."""
        if not self.paced:
            self._pending_out += frame
        else:
            start = max(now, self._tx_wire_s)
            self._tx_wire_s = start + len(frame) * self.byte_time_s
            self._in_flight.append((self._tx_wire_s, frame))
        self.flush(now)

    def flush(self, now: float) -> None:
        while self._in_flight and self._in_flight[0][0] <= now:
            self._pending_out += self._in_flight.pop(0)[1]
        if self._pending_out:
            written = self.port.write(bytes(self._pending_out))
            del self._pending_out[:written]
            if len(self._pending_out) > MAX_PENDING_OUT:
                self.dropped_out_bytes += len(self._pending_out)
                self._pending_out.clear()

    @property
    def backlog_bytes(self) -> int:
        return len(self._pending_out) + sum(len(f) for _, f in self._in_flight)

    def next_tx_deadline(self) -> Optional[float]:
        """When the frame now on the wire will have been sent."""
        return self._in_flight[0][0] if self._in_flight else None

    def close(self) -> None:
        self.port.close()
