"""The host's end of the serial line: one pyserial port, or several redundant ones as one.

`open_lines(url)` reads the address as `aspod sim` prints it: a single pyserial URL or device
(`/dev/pts/5`, `socket://127.0.0.1:5000`), or several links, comma-separated, each optionally named
(`radio=/dev/pts/3,optical=socket://127.0.0.1:40123`). With several, every frame is written on each and
what they bring is joined frame by frame, the first copy kept (host_tools/sessions/redundancy.py); `health`
says what each path has carried.
"""
from __future__ import annotations

import fcntl
import selectors
import struct
import termios

import serial

from protocol.errors import LinkError
from protocol.reasons import Reason
from timebase import Clock
from host_tools.sessions.redundancy import FrameMerger
from host_tools.worlds.ports import check_url, open_url

READ_SIZE = 4096
READ_TIMEOUT_S = 0.001
EMPTY_READY_LIMIT_S = 1.0     # a link the selector finds ready that brings nothing for this long is taken for gone
REOPEN_S = 1.0                # a failed link of several is opened again this often while the line is open


def parse_links(url: str) -> list[tuple[str, str]]:
    """[(name, url)] of a (possibly comma-separated, possibly named) link address; ValueError naming what is
    wrong with it (a link's scheme that pyserial does not know: `worlds.ports.check_url`), before anything is
    opened."""
    items = [item.strip() for item in url.split(",")]
    links = []
    for n, item in enumerate(items):
        name, sep, rest = item.partition("=")
        if sep and name.isidentifier() and "://" not in name:
            links.append((name, rest))
        else:
            links.append(("link" if len(items) == 1 else f"link{n}", item))
    if len(items) > 1 and (any(not u for _, u in links) or len({n for n, _ in links}) != len(links)):
        raise ValueError(f"{url}: links are NAME=URL or URL, comma-separated, each name once")
    for _, link in links:
        check_url(link)
    return links


def _open(url: str, baud: int, timeout: float) -> serial.SerialBase:
    try:
        return open_url(url, baud, timeout, write_timeout=2.0)
    except (serial.SerialException, ValueError) as exc:
        raise LinkError(Reason.NO_SESSION, f"cannot open {url}: {exc}") from exc


class SerialLine:
    """One pyserial port."""

    def __init__(self, url: str, baud: int) -> None:
        self.url = url
        self.serial = _open(url, baud, READ_TIMEOUT_S)

    def read(self) -> bytes:
        """Up to the first byte waits `READ_TIMEOUT_S`; the rest is whatever is already there.

        pyserial's `read(size)` waits out its whole timeout unless `size` bytes come, so read one byte,
        then as many as are waiting. pyserial's `in_waiting` for `socket://` says 0 or 1 (a select), which
        made a read a select and a recv a byte (9 us a byte, 20 kB in 0.18 CPU s); the kernel's count
        (FIONREAD, on a socket, a pty or a tty alike) says them all."""
        data = self.serial.read(1)
        while data and len(data) < READ_SIZE:
            waiting = self._waiting()
            if not waiting:
                break
            data += self.serial.read(min(waiting, READ_SIZE - len(data)))
        return data

    def _waiting(self) -> int:
        try:
            return struct.unpack("i", fcntl.ioctl(self.serial.fileno(), termios.FIONREAD, b"\0\0\0\0"))[0]
        except (OSError, AttributeError, ValueError, serial.SerialException):   # no descriptor (loop://): ask pyserial
            return self.serial.in_waiting

    def write(self, data: bytes) -> None:
        self.serial.write(data)

    def reset_input_buffer(self) -> None:
        self.serial.reset_input_buffer()

    def health(self) -> list[str]:
        return []

    def close(self) -> None:
        self.serial.close()


class RedundantLines:
    """Several pyserial ports as one line: each frame written on all, the first copy of each frame read kept.

    A link that fails (its device gone, its socket closed) is dropped from the set and said in `health`, and
    opened again every `REOPEN_S` while the line is open (a dropped optical link comes back when its beam
    does; the controller admits the connection once a frame of the session comes over it); the line fails
    only when the last link does.
    """

    def __init__(self, links: list[tuple[str, str]], baud: int, clock: Clock) -> None:
        self.url = ",".join(f"{name}={url}" for name, url in links)
        self._clock = clock
        self.ports: dict[str, serial.SerialBase] = {}
        try:
            for name, url in links:
                self.ports[name] = _open(url, baud, 0)
        except LinkError:
            self.close()
            raise
        self.merger = FrameMerger([name for name, _ in links])
        self._urls = dict(links)
        self._baud = baud
        self.failed: dict[str, str] = {}
        self.reopened = 0                              # links opened again after they failed
        self._reopen_s = 0.0
        self._empty_since: dict[str, float] = {}      # links found ready that read nothing, since when
        self._selector = selectors.DefaultSelector()
        for name, port in self.ports.items():
            self._selector.register(port.fileno(), selectors.EVENT_READ, name)

    def _fail(self, name: str, exc: Exception) -> None:
        self.failed[name] = str(exc) or type(exc).__name__
        self._reopen_s = self._clock.now() + REOPEN_S
        port = self.ports.pop(name)
        try:
            self._selector.unregister(port.fileno())
            port.close()
        except (OSError, ValueError, KeyError):
            pass
        if not self.ports:
            raise serial.SerialException("every link failed: " + "; ".join(f"{n}: {e}" for n, e in self.failed.items()))

    def read(self) -> bytes:
        """What the links brought, joined. A link whose other end has gone is dropped: pyserial says so by raising
        (a device ready to read that returns nothing, a socket at its end, an I/O error). A read that returns nothing
        after the selector said ready (pyserial's read without a timeout returns nothing when its own select finds
        nothing, or on EAGAIN) is no proof of that: taken for a closed link, it would drop the link for the rest of
        the session. Such a read waits out `READ_TIMEOUT_S` (a link that stays ready would otherwise make every read
        return at once: a busy loop), and a link ready with nothing to read for `EMPTY_READY_LIMIT_S` is dropped."""
        self._reopen_failed()
        out, came = bytearray(), False
        empty: dict[str, float] = {}
        for key, _ in self._selector.select(READ_TIMEOUT_S):
            name = key.data
            try:
                data = self.ports[name].read(READ_SIZE)
            except (serial.SerialException, OSError) as exc:
                self._fail(name, exc)
                continue
            now = self._clock.now()
            if data:
                came = True
                out += self.merger.feed(name, data, now)
                continue
            since = self._empty_since.get(name, now)
            if now - since < EMPTY_READY_LIMIT_S:
                empty[name] = since
            else:
                self._fail(name, serial.SerialException(f"ready to read, yet nothing came for {now - since:.1f} s"))
        self._empty_since = empty
        if empty and not came:
            self._clock.sleep(READ_TIMEOUT_S)
        return bytes(out)

    def _reopen_failed(self) -> None:
        """Open the failed links again, at most every `REOPEN_S`; one that opens rejoins the line."""
        if not self.failed or self._clock.now() < self._reopen_s:
            return
        self._reopen_s = self._clock.now() + REOPEN_S
        for name in list(self.failed):
            try:
                port = _open(self._urls[name], self._baud, 0)
            except LinkError as exc:
                self.failed[name] = str(exc)
                continue
            del self.failed[name]
            self.ports[name] = port
            self.merger.reset(name)
            self._selector.register(port.fileno(), selectors.EVENT_READ, name)
            self.reopened += 1

    def write(self, data: bytes) -> None:
        for name, port in list(self.ports.items()):
            try:
                port.write(data)
            except (serial.SerialException, OSError) as exc:
                self._fail(name, exc)

    def reset_input_buffer(self) -> None:
        for port in self.ports.values():
            port.reset_input_buffer()

    def health(self) -> list[str]:
        now = self._clock.now()
        return [self.merger.paths[name].describe(now) + (f"; FAILED: {self.failed[name]}" if name in self.failed
                                                         else "") for name in self.merger.paths]

    def close(self) -> None:
        for port in self.ports.values():
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass


def open_lines(url: str, baud: int, clock: Clock) -> "SerialLine | RedundantLines":
    links = parse_links(url)
    if len(links) == 1:
        return SerialLine(links[0][1], baud)
    return RedundantLines(links, baud, clock)

