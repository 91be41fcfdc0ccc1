"""`aspod proxy`: a man in the middle between a host and a controller, impairing, showing and capturing the link.

Each side is any endpoint a serial line can be here (`open_endpoint`): `pty` (a new pseudo-terminal pair:
the other program opens the path the proxy prints), `tcp:PORT` (the proxy listens; `tcp:0` picks a free
port), or a device or pyserial URL the proxy opens itself (`/dev/ttyUSB0`, `/dev/pts/5`,
`socket://127.0.0.1:5000`, `rfc2217://...`). The usual set-up: the controller's side is the port
`aspod sim` announced, the host's side a new pty that teleop opens.

Every frame either way goes through one `ImpairedLink` (host_tools/sessions/impairment.py: pacing,
latency and jitter, bit errors, drops, duplicates, fades, blockages, seeded), the model the lock-step
world uses too. The live view prints each frame decoded (`SessionDecoder`: class, sequence numbers,
message and fields, the MAC verdict with the key) with what the link did to it; the capture keeps
every frame as it was sent, each lost or damaged one with a comment saying what befell it.

When an endpoint the proxy opened goes away (the controller exits, the device is unplugged), it says
which and stops with EXIT_LINK. A host that closes its pty or TCP connection is not an error: the
next one may come. Stopped (SIGINT, SIGTERM), it reads nothing more and delivers what is in flight
(`drain`, at most `DRAIN_S`) before it closes, so that a host's Close passing through is not cut off.

A TCP host side admits clients as the controller's TCP port does (host_tools/worlds/ports.py
`TcpServerPort`): a client that proves nothing never displaces one that proved something. With the
key (`--key-file`) only frames whose MAC verifies prove anything and keep a client live (a Hello: a
key, or a recording of one; a frame of a session the proxy saw begin: the session's host). Without
the key the proxy cannot tell: any frame whose CRC passes counts, so a client that sends well-formed
frames of its own holds the slot as well as a genuine host would (docs/sessions.md).
"""
from __future__ import annotations

import logging
import math
import select
from dataclasses import dataclass, field
from typing import Callable, Optional, TextIO

from protocol.errors import ParseError
from protocol.framing import Frame, decode_frame
from protocol.schema import Direction
from timebase import Clock, RealClock

from host_tools.sessions.capture import CaptureWriter
from host_tools.sessions.decode import HANDSHAKE_IDS, MAC_OK, DecodedFrame, SessionDecoder, describe
from host_tools.sessions.impairment import Fate, ImpairedLine, ImpairedLink

log = logging.getLogger("aspod")
READ_SIZE = 4096
WRITE_SIZE = 65536         # offered to a port at once
MAX_HELD_BYTES = 1 << 20   # one direction's bytes in the link and for its port: beyond, its source is not read
MAX_HELD_FRAMES = 16384    # (and its frames in the link), so a side that does not read, or a flood faster than
                           # the link's pacing, holds the writer back as a full line would, and nothing grows
HOST_LIVE_S = 3.0          # a TCP host that sent a good frame this recently is not displaced by a new connection
IDLE_S = 0.0005            # the loop's sleep when nothing is due sooner: the latency the proxy itself adds
DRAIN_S = 2.0              # stopped: how long what is in flight may still take to be delivered


class EndpointGone(Exception):
    """An endpoint the proxy opened failed: `side` says which."""

    def __init__(self, side: str, url: str, reason: str) -> None:
        super().__init__(f"the {side} side ({url}) is gone: {reason}")
        self.side = side


@dataclass
class _Side:
    name: str            # "host" or "controller"
    port: object
    outgoing: bytearray = field(default_factory=bytearray)   # delivered by the link, not yet taken by the port
    generation: int = 0  # the port's client (a tcp: side counts changes of client): the one the link cuts for


class Proxy:
    """Forwards both ways through `link`; `step()` does what is due now, `run(should_stop)` loops."""

    def __init__(self, host_port, controller_port, link: ImpairedLink, *, clock: Optional[Clock] = None,
                 view: Optional[TextIO] = None, capture: Optional[CaptureWriter] = None,
                 psk: Optional[bytes] = None, capture_name: str = "the capture") -> None:
        self.clock = clock or RealClock()
        self.origin = self.clock.now()
        self.link = link
        self.host = _Side("host", host_port)
        self.controller = _Side("controller", controller_port)
        self.view = view
        self.view_skipped = 0             # lines the view's reader had no room for (a paused pager, say)
        self.capture = capture
        self.capture_name = capture_name
        self.capture_failed = ""          # why the capture stopped, if it could not be written
        self.decoder = SessionDecoder(psk)
        self._psk = psk
        self.frames = 0
        # A TCP host port takes a new connection in place of a client without a live session, never of one with
        # (host_tools/worlds/ports.py): the proxy knows no session, so a client whose frames pass their CRC is
        # live while it sent one within HOST_LIVE_S (the link's default timeout). Its token is new for each client.
        self._host_frame_s = -math.inf
        self._host_token: Optional[object] = None
        self._host_serves_clients = hasattr(host_port, "live_session")
        if self._host_serves_clients:
            host_port.live_session = self._host_session
            host_port.vouch = self._vouch

    def _host_session(self) -> Optional[object]:
        live = self.clock.now() - self.origin - self._host_frame_s <= HOST_LIVE_S
        return self._host_token if live else None

    def _vouch(self, frame: Frame) -> int:
        """What a frame from a client waiting for the host side proves (`TcpServerPort.vouch`): without the key,
        any frame 1; with it, a Hello that verifies 1, a frame of a session seen to begin 2, else nothing."""
        if self._psk is None:
            return 1
        if self.decoder.mac_verdict(frame, Direction.TO_CONTROLLER) != MAC_OK:
            return 0
        return 1 if frame.msg_id in HANDSHAKE_IDS else 2

    def _host_sent(self, decoded: list[Optional[DecodedFrame]], fates: list[Fate], t: float) -> None:
        """Note a good frame from the host: its client is live. Good: with the key, its MAC verifies; without it,
        its CRC passes (anyone can make such a frame: the docs say so)."""
        for d, fate in zip(decoded, fates):
            if self._psk is not None:
                if d is None or d.frame is None or d.mac != MAC_OK:
                    continue
            else:
                try:
                    decode_frame(fate.sent.strip(b"\x00"))
                except ParseError:
                    continue
            self._host_frame_s = t
            if self._host_token is None:
                self._host_token = object()

    def _read(self, side: _Side) -> bytes:
        try:
            return side.port.read(READ_SIZE)
        except OSError as exc:
            raise EndpointGone(side.name, side.port.url, str(exc) or type(exc).__name__) from None

    def _write(self, side: _Side) -> None:
        if not side.outgoing:
            return
        try:
            written = side.port.write(bytes(side.outgoing[:WRITE_SIZE]))
        except OSError as exc:
            raise EndpointGone(side.name, side.port.url, str(exc) or type(exc).__name__) from None
        del side.outgoing[:written]

    def step(self) -> float:
        """Move what is there and what is due; returns the time (link time) when something is next due."""
        t = self.clock.now() - self.origin
        for source, line, direction, target in (
                (self.host, self.link.to_controller, Direction.TO_CONTROLLER, self.controller),
                (self.controller, self.link.to_host, Direction.TO_HOST, self.host)):
            if self._full(line, target):
                continue         # left in the source's buffer until the far side takes what is held
            data = self._read(source)
            generation = getattr(source.port, "generation", 0)
            if generation != source.generation:     # a new client: what the old one left is not its
                source.generation = generation
                if source is self.host:
                    self._host_token, self._host_frame_s = None, -math.inf     # the new client is not live yet
                forgotten = line.restart() + len(target.outgoing)
                target.outgoing.clear()
                if forgotten:
                    log.info(f"aspod proxy: a new {source.name} client: {forgotten} B the previous one wrote, "
                             "not yet delivered, are dropped")
            if data:
                fates = line.send(data, t)
                decoded = [self._decode(fate, direction, t) for fate in fates]
                if source is self.host and self._host_serves_clients:
                    self._host_sent(decoded, fates, t)
                for fate, d in zip(fates, decoded):
                    self._show(fate, direction, d)
        self._deliver(t)
        return self.link.next_due_s()

    def _deliver(self, t: float) -> None:
        for line, target in ((self.link.to_controller, self.controller), (self.link.to_host, self.host)):
            target.outgoing += line.receive(t)
            self._write(target)

    def drain(self, within_s: float = DRAIN_S) -> None:
        """Stopping: read nothing more, deliver what is in flight (at most `within_s`, the link's latency and
        pacing), so that a frame already sent, a host's Close say, reaches its end."""
        deadline = self.clock.now() + within_s
        while self.clock.now() < deadline:
            t = self.clock.now() - self.origin
            self._deliver(t)
            if not (self.link.to_controller.in_flight or self.link.to_host.in_flight
                    or self.host.outgoing or self.controller.outgoing):
                return
            due = self.link.next_due_s()
            self.clock.sleep(max(0.0, min(IDLE_S, due - t)))

    def _decode(self, fate: Fate, direction: Direction, t: float) -> Optional[DecodedFrame]:
        """The frame as sent, decoded (MAC verified with the key), when the view or the key needs it."""
        if self.view is None and self._psk is None:
            return None
        return self.decoder.decode(fate.sent.strip(b"\x00"), t, "link", direction)

    @staticmethod
    def _full(line: ImpairedLine, target: _Side) -> bool:
        return line.held_bytes + len(target.outgoing) >= MAX_HELD_BYTES or line.in_flight >= MAX_HELD_FRAMES

    def _show(self, fate: Fate, direction: Direction, decoded: Optional[DecodedFrame]) -> None:
        self.frames += 1
        note = fate.describe()
        if self.capture is not None:
            try:
                self.capture.write("link", direction, fate.sent, RealClock.wall_time(), comment=note)
            except OSError as exc:        # a full disk, say: the capture stops there, the link goes on
                kept = "" if self.capture.partial is None else \
                    f"; the destination is left as it was, and {self.capture.partial} holds them"
                self.capture_failed = f"{self.capture_name} cannot be written ({exc.strerror or exc}): the frames " \
                                      f"before frame {self.frames} are kept, cut short{kept}"
                log.error(f"aspod proxy: {self.capture_failed}; the link goes on")
                self._close_capture()
        if self.view is not None and decoded is not None and self._view_has_room():
            print(describe(decoded) + (f"  [{note}]" if note else ""), file=self.view, flush=True)

    def _view_has_room(self) -> bool:
        """Whether the view can take a line now: a reader that stops reading it (a paused pager, a full pipe) must
        neither stall the link nor make the proxy deaf to Ctrl-C, so the lines it has no room for are skipped."""
        try:
            fd = self.view.fileno()
        except (AttributeError, OSError, ValueError):   # not a file (a test's buffer): it always has room
            return True
        poll = select.poll()
        poll.register(fd, select.POLLOUT)
        if poll.poll(0):
            return True
        if not self.view_skipped:
            log.warning("aspod proxy: the live view's reader is not keeping up: lines are skipped, the link goes on")
        self.view_skipped += 1
        return False

    def run(self, should_stop: Callable[[], bool]) -> None:
        while not should_stop():
            due = self.step()
            now = self.clock.now() - self.origin
            self.clock.sleep(max(0.0, min(IDLE_S, due - now)))

    def summary(self) -> str:
        lines = []
        for name, line, target in (("host -> controller", self.link.to_controller, self.controller),
                                   ("controller -> host", self.link.to_host, self.host)):
            s = line.stats
            lines.append(f"{name}: {s.frames} frames ({s.bytes_in} B in, {s.bytes_out} B out); lost: {s.dropped} "
                         f"dropped, {s.faded} in fades, {s.blocked} in blockages; {s.duplicated} duplicated; "
                         f"{s.bits_flipped} bits flipped")
            if line.in_flight or target.outgoing:       # what stopping the proxy leaves undelivered
                lines[-1] += (f"; not delivered at the end: {line.in_flight} frames in flight, "
                              f"{len(target.outgoing)} B the {target.name} had not taken")
        if self.view_skipped:
            lines.append(f"live view: {self.view_skipped} frames not shown (its reader did not keep up)")
        return "\n".join(lines)

    def close(self) -> None:
        for side in (self.host, self.controller):
            try:
                side.port.close()
            except OSError:
                pass
        self._close_capture()

    def _close_capture(self) -> None:
        capture, self.capture = self.capture, None
        if capture is not None:
            try:
                capture.close()
            except OSError:               # the last bytes cannot be written either: said when writing failed
                pass

