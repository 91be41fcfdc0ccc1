"""The controller's serial port: where its bytes meet a pty, a TCP client or a device.

Ports are non-blocking byte pipes (`read(max_bytes)`, `write(data) -> int`). The host
side always goes through pyserial (`serial_for_url`); the controller side owns the
other end, which pyserial cannot serve: the master of a pty pair, a listening TCP
socket, or a real device (that one through pyserial).

`PacedUart` emulates the wire time of an 8N1 line (10 bits a byte) at the configured
baud in both directions: bytes a host writes in a burst reach the protocol no faster
than the line would carry them, and a frame the controller sends reaches the host
when its last bit would have. A pty ignores the baud rate entirely, so without this
a host would see no line timing at all.
"""
from __future__ import annotations

import errno
import os
import socket
import termios
import tty
from typing import Callable, Optional, Protocol

BAUD_RATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800)
BITS_PER_BYTE = 10            # 8N1: start + 8 data + stop
MAX_PENDING_OUT = 64 * 1024   # bytes held for a host that is not reading before they are dropped
RX_LOOKAHEAD = 4096           # bytes read ahead from the OS while the line delivers them


class Port(Protocol):
    url: str

    def read(self, max_bytes: int) -> bytes: ...
    def write(self, data: bytes) -> int: ...
    def close(self) -> None: ...


class PtyPort:
    """The controller holds the master of a new pty pair; a host opens `url` (the slave)."""

    def __init__(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave, termios.TCSANOW)   # binary frames: no echo, no line discipline
        os.set_blocking(self._master, False)
        self.url = os.ttyname(self._slave)

    def read(self, max_bytes: int) -> bytes:
        try:
            return os.read(self._master, max_bytes)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:   # no reader on the slave side right now
                return b""
            raise

    def write(self, data: bytes) -> int:
        try:
            return os.write(self._master, data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError as exc:
            if exc.errno == errno.EIO:
                return len(data)   # nobody is listening: the bytes are gone, as on a real line
            raise

    def close(self) -> None:
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


class TcpServerPort:
    """Listens on 127.0.0.1:`port`; one client at a time is the line's other end.

    Who holds the line: a new connection never displaces a client that carries a live
    authenticated session; a client that has not brought one (no session since it connected, or
    its session's link timed out) is displaced by a newer connection, so that an idle squatter
    cannot lock the genuine host out either. A refused connection is closed at once and counted
    in `refused`. The port learns about sessions from `live_session`, assigned by whoever builds
    the controller (host_tools/nodes.py `build_controller`): it returns a token naming the live
    session (or None when there is none, or its link timed out). The client "brought" the session
    if the token is not the one that was live when the client connected.

    Every change of client (a new one, or the present one closing) increments `generation`: the
    paced UART then discards what it still held of the old client's bytes (`PacedUart.receive`),
    so that nothing the old client wrote reaches the controller as if the new one had sent it.
    """

    MAX_ACCEPTS_PER_READ = 8    # connections taken (or refused) per read: a flood cannot stall the comms task

    def __init__(self, port: int, host: str = "127.0.0.1") -> None:
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((host, port))
        self._listener.listen(4)
        self._listener.setblocking(False)
        self._client: Optional[socket.socket] = None
        self._session_at_connect: object = None    # the live session's token when the client connected
        self.port = self._listener.getsockname()[1]
        self.url = f"socket://{host}:{self.port}"
        self.live_session: Callable[[], object] = lambda: None
        self.on_refused: Callable[[str], None] = lambda peer: None   # told "host:port" of each refused
        self.connections = 0     # clients that became the line's other end
        self.refused = 0         # connections closed at once: the present client carries a live session
        self.generation = 0      # changes of client (connected, replaced, gone)

    def client_has_session(self) -> bool:
        """The present client brought the live session (it came after the client connected)."""
        if self._client is None:
            return False
        token = self.live_session()
        return token is not None and token is not self._session_at_connect

    def _accept(self) -> None:
        for _ in range(self.MAX_ACCEPTS_PER_READ):
            try:
                client, addr = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:        # a connection reset before it was taken, say
                continue
            if self.client_has_session():
                client.close()
                self.refused += 1
                self.on_refused(f"{addr[0]}:{addr[1]}")
                continue
            client.setblocking(False)
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._drop_client()
            self._client = client
            self._session_at_connect = self.live_session()
            self.connections += 1

    def _drop_client(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
            self.generation += 1

    def read(self, max_bytes: int) -> bytes:
        """The present client's bytes; then new connections are taken or refused. Bytes of a client that
        left or was replaced during this read are not returned (they were not the new client's)."""
        generation = self.generation
        data = self._receive(max_bytes) if self._client is not None else b""
        self._accept()     # after the present client's end of stream, if it came, was seen
        return data if self.generation == generation else b""

    def _receive(self, max_bytes: int) -> bytes:
        """Up to `max_bytes` from the present client; the client is dropped at its end of stream."""
        try:
            data = self._client.recv(max_bytes)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            data = b""
        gone = not data
        if data and len(data) < max_bytes:      # all it had: has it closed behind them?
            try:
                gone = self._client.recv(1, socket.MSG_PEEK) == b""
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                gone = True
        if gone:
            self._drop_client()
        return data

    def write(self, data: bytes) -> int:
        if self._client is None:
            return len(data)   # no host: the bytes are gone
        try:
            return self._client.send(data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            self._drop_client()
            return len(data)

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
        self._listener.close()


class DevicePort:
    """A real serial device (or any pyserial URL) opened non-blocking."""

    def __init__(self, url: str, baud: int) -> None:
        import serial   # only this port needs pyserial on the controller side
        self._serial = serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=0)
        self.url = url

    def read(self, max_bytes: int) -> bytes:
        return self._serial.read(max_bytes)

    def write(self, data: bytes) -> int:
        import serial
        try:
            return self._serial.write(data) or 0
        except serial.SerialTimeoutException:
            return 0

    def close(self) -> None:
        self._serial.close()


class BufferPort:
    """An in-memory port for lock-step worlds: the other side fills `inbox`, drains `outbox`.

    With `notifies` it says when bytes move, so that neither end has to poll it:
    `deliver(data)` (the other side's write) calls `on_input`, `write` calls `on_output`. A
    comms task over such a port sleeps through the polls that would find nothing
    (`firmware_py/comms.py`).
    """

    def __init__(self, url: str = "memory://", notifies: bool = True) -> None:
        self.url = url
        self.notifies = notifies
        self.inbox = bytearray()
        self.outbox = bytearray()
        self.on_input: Callable[[], None] = lambda: None
        self.on_output: Callable[[], None] = lambda: None

    def deliver(self, data: bytes) -> None:
        """The other side writes `data` (it reaches `read`); `on_input` is told."""
        if data:
            self.inbox += data
            self.on_input()

    def read(self, max_bytes: int) -> bytes:
        if not self.inbox:
            return b""
        data = bytes(self.inbox[:max_bytes])
        del self.inbox[:max_bytes]
        return data

    def write(self, data: bytes) -> int:
        self.outbox += data
        self.on_output()
        return len(data)

    def close(self) -> None:
        pass


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
