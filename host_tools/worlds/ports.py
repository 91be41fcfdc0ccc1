"""The OS ports a controller's serial line can sit on: where its bytes meet a pty, a TCP client,
a device or memory.

Ports are non-blocking byte pipes (`read(max_bytes)`, `write(data) -> int`; the interface is
`firmware_py.uart.Port`). The host side always goes through pyserial (`serial_for_url`); the
controller side owns the other end, which pyserial cannot serve: the master of a pty pair, a
listening TCP socket, or a real device (that one through pyserial). `BufferPort` is the
in-memory line of the lock-step worlds. The controller's `PacedUart` paces any of them to the
line's baud rate.
"""
from __future__ import annotations

import errno
import math
import os
import select
import socket
import termios
import tty
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Optional

from protocol.controller_link import VOUCH_LIVE_SESSION
from protocol.framing import Frame, FrameReceiver
from protocol.schema import Direction
from timebase import Clock, RealClock
from host_tools.sessions.redundancy import FrameMerger

if TYPE_CHECKING:
    from host_tools.sessions.capture import CaptureWriter



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


@dataclass(eq=False)
class _Candidate:
    """A connection waiting for the line: what it sent (kept, not delivered) and what that proved."""

    sock: socket.socket
    since_s: float
    rx: FrameReceiver = field(default_factory=FrameReceiver)
    sent: bytearray = field(default_factory=bytearray)
    proof: int = 0              # the most any of its frames proved (`vouch`)
    proof_s: float = math.inf   # when it proved that much


class TcpServerPort:
    """Listens on 127.0.0.1:`port`; one client at a time is the line's other end, admitted by what it proves.

    - A client that brought the live authenticated session keeps the line: a newcomer is closed at once and
      counted in `refused`. The port learns about sessions from `live_session` (a token naming the live
      session, or None) and judges frames with `vouch(frame) -> int`, both assigned by whoever builds the
      controller (host_tools/worlds/nodes.py `build_controller`; `ControllerLink.vouch`): 1 a Hello that
      verifies (the key, or a recording of it), 2 a host that holds the key now (a Hello with a fresh cookie,
      a frame of a pending session), 3 the live session's host. The client "brought" the session if the
      token is not the one that was live when it connected.
    - Otherwise a newcomer waits as a *candidate* (at most `MAX_CANDIDATES`, each at most `CANDIDATE_WAIT_S`):
      its bytes are read and kept (at most `CANDIDATE_BYTES`) but not delivered, and its frames judged. The
      line goes to the candidate that proved most (the first to prove it among equals) when that is more
      than the present client proved; a client's proof counts for `HANDSHAKE_GRACE_S` (a handshake's time),
      unless it brought the live session. So a client that proves nothing never displaces one in its
      handshake (a keyless loop connecting every few ms cannot keep a host off), and an idle squatter holds
      the line only until someone proves anything. A free line goes to the first candidate at once, whatever
      it proved (a line no one is on serves anyone, as a serial port would). With the candidates full, the
      oldest that sent nothing leaves, else the oldest that proved least (counted in `dropped`).
    - `live_only` (a link of several, `RedundantPort`): while a session is live, only its host is admitted.

    A promoted candidate's bytes are the first the line delivers from it, so its Hello is not lost. Every
    change of client (a new one, or the present one closing) increments `generation`: the paced UART then
    discards what it still held of the old client's bytes (`PacedUart.receive`), so that nothing the old
    client wrote reaches the controller as if the new one had sent it.
    """

    MAX_ACCEPTS_PER_READ = 8    # connections taken per read: a flood cannot stall the comms task
    # connections the kernel completes before they are taken: with 4, a sixth connection within one read waited for
    # its SYN to be sent again, 1 s later (300 connections one after another: 51 waited, 52 s in all; with 64: 3, 3 s)
    LISTEN_BACKLOG = 64
    MAX_CANDIDATES = 16
    CANDIDATE_WAIT_S = 10.0     # a candidate not admitted by then is closed
    CANDIDATE_BYTES = 4096      # what a candidate sent, kept for the line (its handshake needs less than 200 B)
    HANDSHAKE_GRACE_S = 3.0     # how long what a client proved keeps it on the line without a live session

    def __init__(self, port: int, host: str = "127.0.0.1", clock: Optional[Clock] = None) -> None:
        self._clock = clock or RealClock()
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((host, port))
        self._listener.listen(self.LISTEN_BACKLOG)
        self._listener.setblocking(False)
        self._client: Optional[socket.socket] = None
        self._session_at_connect: object = None    # the live session's token when the client connected
        self._holder = _Candidate(socket.socket(), 0.0)     # what the client on the line proved (a placeholder)
        self._holder.sock.close()
        self._candidates: list[_Candidate] = []
        self.port = self._listener.getsockname()[1]
        self.url = f"socket://{host}:{self.port}"
        self.live_session: Callable[[], object] = lambda: None
        self.vouch: Callable[[Frame], int] = lambda frame: 0
        self.live_only = False
        self.on_refused: Callable[[str], None] = lambda peer: None   # told "host:port" of each refused
        self.connections = 0     # clients that became the line's other end
        self.refused = 0         # connections closed at once: the present client carries a live session
        self.dropped = 0         # candidates closed: too many waited, or one waited too long
        self.generation = 0      # changes of client (connected, replaced, gone)
        self._client_left = False   # the last read found the client gone (its end of stream)

    def client_has_session(self) -> bool:
        """The present client brought the live session (it came after the client connected)."""
        if self._client is None:
            return False
        token = self.live_session()
        return token is not None and token is not self._session_at_connect

    # ---- who holds the line ----
    def _accept(self, now: float) -> None:
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
            if len(self._candidates) >= self.MAX_CANDIDATES:
                self._drop(min(self._candidates, key=lambda c: (bool(c.sent), c.proof, c.since_s)))
            self._candidates.append(_Candidate(client, now))

    def _drop(self, candidate: _Candidate) -> None:
        self._candidates.remove(candidate)
        candidate.sock.close()
        self.dropped += 1

    def _hear_candidates(self) -> None:
        """Read what each candidate sent (kept, judged); one that closed is forgotten."""
        for candidate in list(self._candidates):
            try:
                data = candidate.sock.recv(self.CANDIDATE_BYTES)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                data = b""
            if not data:
                self._candidates.remove(candidate)
                candidate.sock.close()
                continue
            candidate.sent += data
            del candidate.sent[:-self.CANDIDATE_BYTES]
            self._judge(candidate, data)

    def _judge(self, who: _Candidate, data: bytes) -> None:
        for frame in who.rx.feed(data):
            if isinstance(frame, Frame):
                proof = self.vouch(frame)
                if proof > who.proof:
                    who.proof, who.proof_s = proof, self._clock.now()

    def _holder_proof(self, now: float) -> int:
        """What the client on the line proved, as far as it still counts (0: no client)."""
        if self._client is None:
            return -1
        if now - self._holder.proof_s > self.HANDSHAKE_GRACE_S:
            return 0
        return self._holder.proof

    def _admit(self, now: float) -> Optional[bytes]:
        """Give the line to the candidate that earned it, if one did: its bytes so far (None: nobody new)."""
        stale = [c for c in self._candidates if now - c.since_s > self.CANDIDATE_WAIT_S]
        if self.client_has_session():           # the line is taken for the session's life: no one waits for it
            stale = list(self._candidates)
            self.refused += len(stale)
            self.dropped -= len(stale)
        for candidate in stale:
            self._drop(candidate)
        if not self._candidates:
            return None
        needed = self._holder_proof(now) + 1    # a free line (-1 + 1): anyone, the one that proved most first
        if self.live_only and self.live_session() is not None:
            needed = max(needed, VOUCH_LIVE_SESSION)
        best = max(self._candidates, key=lambda c: (c.proof, -c.proof_s, -c.since_s))
        if best.proof < needed:
            return None
        self._candidates.remove(best)
        self._drop_client()
        self._client, self._holder = best.sock, best
        self._session_at_connect = self.live_session()
        self.connections += 1
        return bytes(best.sent)

    def _drop_client(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
            self.generation += 1

    def read(self, max_bytes: int) -> bytes:
        """The present client's bytes, judged while it has no live session; then newcomers are taken, heard and
        perhaps admitted. Bytes of a client replaced during this read are not returned (they were not the new
        client's); a client that closed returns its last bytes (written before it closed, as a host's last Ack
        is), and a client admitted in the read brings what it sent while it waited, after them."""
        now = self._clock.now()
        data = self._receive(max_bytes) if self._client is not None else b""
        if data and not self.client_has_session():
            self._judge(self._holder, data)
        generation = self.generation      # after the present client's end of stream, if it came with its last bytes
        self._accept(now)
        self._hear_candidates()
        admitted = self._admit(now)
        if admitted is not None:          # a client displaced: none of its bytes; one that left: its last ones first
            return (data if self._client_left else b"") + admitted
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
        self._client_left = gone
        if gone:          # its last bytes are still its own: a host's last Ack before it closes (protocol.md)
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
        for candidate in self._candidates:
            candidate.sock.close()
        self._candidates.clear()
        self._listener.close()


class DevicePort:
    """A real serial device (or any pyserial URL) opened non-blocking."""

    def __init__(self, url: str, baud: int) -> None:
        self._serial = open_url(url, baud, timeout=0, write_timeout=0)
        self.url = url

    def read(self, max_bytes: int) -> bytes:
        return self._serial.read(max_bytes)

    def write(self, data: bytes) -> int:
        """What the device takes now (0 if it takes nothing). pyserial's own non-blocking write spins until the
        device takes a first byte (it retries EAGAIN), so a device or socket that is not read would hold the
        caller for ever, deaf to Ctrl-C: asked first whether it can take any."""
        import serial
        fileno = getattr(self._serial, "fileno", None)
        if fileno is not None:
            poll = select.poll()          # (poll, not select: any descriptor number)
            poll.register(fileno(), select.POLLOUT)
            if not poll.poll(0):
                return 0
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


def exchange(port: BufferPort, host, now: float) -> None:
    """A host link's turn on an in-memory line: what the controller wrote to `port` in, the link's timers, what it
    has to send out (a `protocol.host_link.HostLink`, polled on a clock of the caller's)."""
    if port.outbox:
        host.feed(bytes(port.outbox), now)
        port.outbox.clear()
    host.poll(now)
    out = host.take_all(now)
    if out:
        port.deliver(out)


class RecordedPort:
    """Any port above, with every byte the controller reads and writes kept in a session capture.

    Seen from the controller's end: what it reads went host -> controller, what it writes the
    other way (only the bytes the port took). Each frame is stamped with `clock`'s time when its
    closing delimiter passed. The port's other attributes (`url`, `generation`, `live_session`)
    are the wrapped port's.
    """

    def __init__(self, port, capture: "CaptureWriter", clock, link: str = "link") -> None:
        self.__dict__.update(_port=port, _capture=capture, _clock=clock, _link=link)

    def read(self, max_bytes: int) -> bytes:
        data = self._port.read(max_bytes)
        if data:
            self._capture.write(self._link, Direction.TO_CONTROLLER, data, self._clock.now())
        return data

    def write(self, data: bytes) -> int:
        written = self._port.write(data)
        if written:
            self._capture.write(self._link, Direction.TO_HOST, bytes(data[:written]), self._clock.now())
        return written

    def close(self) -> None:
        try:
            self._port.close()
        finally:
            self._capture.close()

    def __getattr__(self, name: str):
        return getattr(self._port, name)

    def __setattr__(self, name: str, value) -> None:
        setattr(self._port, name, value)


def url_schemes() -> tuple[str, ...]:
    """The schemes pyserial opens (`socket`, `rfc2217`, `loop`, ...): the names of its URL handlers, found where
    pyserial itself looks for them (`serial.protocol_handler_packages`)."""
    import importlib
    import pkgutil
    import serial
    names = set()
    for package in serial.protocol_handler_packages:
        for module in pkgutil.iter_modules(importlib.import_module(package).__path__):
            if module.name.startswith("protocol_"):
                names.add(module.name[len("protocol_"):])
    return tuple(sorted(names))


def check_url(url: str) -> None:
    """A device path, or a pyserial URL whose scheme pyserial knows (a `socket://` one as HOST:PORT): ValueError
    naming what is wrong, before anything is opened (pyserial's own complaint about a bad socket URL names its
    logging options)."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        if not url:
            raise ValueError("an empty link address: give a device (/dev/pts/N) or a URL (socket://HOST:PORT)")
        return
    scheme = scheme.lower()          # as pyserial reads it
    if scheme not in url_schemes():
        raise ValueError(f"{url}: unknown link scheme {scheme}://; a link is a device (/dev/pts/N) or a URL "
                         f"with one of the schemes {', '.join(s + '://' for s in url_schemes())}")
    if scheme in ("socket", "rfc2217"):
        host, sep, port = rest.split("?", 1)[0].rpartition(":")
        if not (sep and host and port.isdigit() and 1 <= int(port) <= 65535):
            article = "an" if scheme == "rfc2217" else "a"
            raise ValueError(f"{url}: {article} {scheme} link is {scheme}://HOST:PORT, PORT a number 1..65535")


def open_url(url: str, baud: int, timeout: Optional[float], write_timeout: Optional[float]):
    """The pyserial port of `url` (`check_url` first: ValueError naming what is wrong), sending each write as it
    is made: on `socket://` pyserial leaves Nagle's algorithm on, and a small frame written while the last was
    not yet acknowledged waited for the peer's delayed ACK, 40 ms on Linux (the black-box fuzzer's commands were
    answered in 43 ms, 3 ms with it off: measured). pyserial's SerialException on a failure to open."""
    import serial
    check_url(url)
    port = serial.serial_for_url(url, baudrate=baud, timeout=timeout, write_timeout=write_timeout)
    sock = getattr(port, "_socket", None)        # (pyserial's socket://: no public handle)
    if isinstance(sock, socket.socket) and sock.family in (socket.AF_INET, socket.AF_INET6):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return port


def tcp_port(spec: str) -> Optional[int]:
    """The port of an endpoint `tcp:PORT`, None for any other endpoint; ValueError naming a bad one."""
    if not spec.startswith("tcp:"):
        return None
    try:
        port = int(spec[4:])
    except ValueError:
        raise ValueError(f"{spec}: write tcp:PORT with a port number (tcp:0 picks a free one)") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"{spec}: a TCP port is within 0..65535")
    return port


def check_endpoint(spec: str) -> None:
    """`pty`, `tcp:PORT` or a device / pyserial URL (`check_url`): ValueError naming what is wrong."""
    if spec != "pty" and tcp_port(spec) is None:
        check_url(spec)


def open_endpoint(spec: str, baud: int):
    """`pty` (a new pseudo-terminal pair), `tcp:PORT` (listen; tcp:0 picks a port) or a device / pyserial URL
    (opened here): the port (read, write, close, url). ValueError naming `spec` if it is none of them (before
    anything is opened), OSError if it cannot be opened."""
    check_endpoint(spec)
    if spec == "pty":
        return PtyPort()
    port = tcp_port(spec)
    if port is not None:
        return TcpServerPort(port)
    import serial
    try:
        return DevicePort(spec, baud)
    except (serial.SerialException, ValueError) as exc:
        raise OSError(f"cannot open {spec}: {exc}") from None


class RedundantPort:
    """Several ports as one line (the report's redundant links): every byte written goes to all of them, and
    what they bring is joined frame by frame, the first copy of each frame kept (`FrameMerger`).

    A port that cannot take its bytes now keeps them (at most `BACKLOG` bytes; beyond that the oldest are
    lost, as on a line nobody reads) and is offered them again at the next write or read. `url` names every
    link: `radio=/dev/pts/3,optical=socket://127.0.0.1:40123`, which the host tools take as it is.
    """

    BACKLOG = 64 * 1024

    def __init__(self, ports: dict[str, object], clock) -> None:
        self.ports = dict(ports)
        self.merger = FrameMerger(list(self.ports))
        self._clock = clock
        self._out = {name: bytearray() for name in self.ports}
        self._generations = {name: getattr(port, "generation", 0) for name, port in self.ports.items()}
        self._ready = bytearray()
        self.lost_bytes = {name: 0 for name in self.ports}
        self.url = ",".join(f"{name}={port.url}" for name, port in self.ports.items())
        for port in self.ports.values():
            if hasattr(port, "live_only"):     # a TCP link of several: while the session lives, its host only
                port.live_only = True

    @property
    def live_session(self):
        """The session guard of its links that have one (TCP); none has one (ptys, devices): AttributeError, so
        that `hasattr` says no, as for a single such port."""
        for port in self.ports.values():
            if hasattr(port, "live_session"):
                return port.live_session
        raise AttributeError("live_session: none of these links guards its line (only a TCP link does)")

    @live_session.setter
    def live_session(self, value) -> None:
        for port in self.ports.values():
            if hasattr(port, "live_session"):
                port.live_session = value

    @property
    def vouch(self):
        for port in self.ports.values():
            if hasattr(port, "vouch"):
                return port.vouch
        raise AttributeError("vouch: no link of this line admits connections")

    @vouch.setter
    def vouch(self, value) -> None:
        for port in self.ports.values():
            if hasattr(port, "vouch"):
                port.vouch = value

    def read(self, max_bytes: int) -> bytes:
        now = self._clock.now()
        for name, port in self.ports.items():
            data = port.read(4096)
            generation = getattr(port, "generation", 0)
            if generation != self._generations[name]:       # another client on that link: its half frame goes
                self._generations[name] = generation
                self.merger.reset(name)
            if data:
                self._ready += self.merger.feed(name, data, now)
        self._flush()
        out = bytes(self._ready[:max_bytes])
        del self._ready[:max_bytes]
        return out

    def write(self, data: bytes) -> int:
        for name in self.ports:
            self._out[name] += data
        self._flush()
        return len(data)

    def _flush(self) -> None:
        for name, port in self.ports.items():
            pending = self._out[name]
            if pending:
                del pending[:port.write(bytes(pending))]
            if len(pending) > self.BACKLOG:
                self.lost_bytes[name] += len(pending) - self.BACKLOG
                del pending[:len(pending) - self.BACKLOG]

    def close(self) -> None:
        for port in self.ports.values():
            port.close()
