"""A man in the middle of a real line, for attack tests against `aspod sim` subprocesses.

`LineTap(url)` opens the controller's port (a pty path or `socket://127.0.0.1:PORT`, through
pyserial as a host would) and serves the host a port of the same kind, as `aspod sim` does
(`tap.url`: a new pty, or a TCP port). Every frame goes on whole, both ways, from a thread of
its own, and is recorded. The attacker's side: `inject_to_controller` / `inject_to_host` put
recorded frames onto the line between two whole frames; `flood(frames, bytes_per_s)` replays
frames, in turn, at a steady byte rate; `drop_after(msg_id)` passes the host's frames up to the
first of that message, then loses all it sends (an Ack that never arrives) up to a frame with id `until`
(a new host's Hello: it passes, whenever the last bytes of the old host reach the tap) or `drop_after(None)`;
`retarget(url)` puts another controller behind the same line (a restart behind a radio link that
stays up).
"""
from __future__ import annotations

import os
import queue
import selectors
import threading
from typing import Optional

import serial

from firmware_py.uart import Port
from host_tools.worlds.ports import DevicePort, PtyPort, TcpServerPort
from protocol.errors import ParseError
from protocol.framing import Frame, decode_frame
from timebase import RealClock

MAX_BACKLOG = 256 * 1024     # bytes held for a side that does not read before they are dropped
POLL_S = 0.001


def whole_frames(data: bytes) -> list[bytes]:
    """The frames in recorded bytes, each as it went on the wire (0x00 COBS 0x00)."""
    return [b"\x00" + s + b"\x00" for s in bytes(data).split(b"\x00") if s]


def decoded(data: bytes) -> list[tuple[Frame, bytes]]:
    """(frame, its wire bytes) for every frame in recorded bytes whose CRC checks out."""
    out = []
    for wire in whole_frames(data):
        try:
            out.append((decode_frame(wire[1:-1]), wire))
        except ParseError:
            pass
    return out


class _Direction:
    """Bytes one way: what was read but is not yet a whole frame, what waits to be written."""

    def __init__(self) -> None:
        self.partial = bytearray()
        self.out = bytearray()
        self.record = bytearray()

    def take_whole(self, data: bytes) -> bytes:
        """Bytes read: the whole frames among them so far (recorded); the rest waits for its end."""
        self.partial += data
        end = self.partial.rfind(0)
        if end < 0:
            return b""
        whole = bytes(self.partial[:end + 1])
        del self.partial[:end + 1]
        self.record += whole
        return whole

    def queue(self, data: bytes) -> None:
        self.out += data
        if len(self.out) > MAX_BACKLOG:
            self.out.clear()

    def write(self, port: Optional[Port]) -> None:
        if not self.out:
            return
        try:
            written = port.write(bytes(self.out)) if port is not None else len(self.out)
        except (OSError, serial.SerialException):
            written = len(self.out)           # that side is gone: the bytes are lost, as on a line
        del self.out[:written]


class LineTap:
    def __init__(self, target_url: str, clock: Optional[RealClock] = None) -> None:
        self.clock = clock or RealClock()
        self._drop_after: Optional[int] = None
        self._drop_until: Optional[int] = None
        self.dropping = False                 # the host's frames are being lost
        self.frames_dropped = 0               # of the host's, by `drop_after`
        self.injected_bytes = 0
        self._up = _Direction()               # host -> controller
        self._down = _Direction()             # controller -> host
        self._commands: "queue.Queue" = queue.Queue()
        self._sel = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._sel.register(self._wake_r, selectors.EVENT_READ)
        self._host: Port = TcpServerPort(0) if target_url.startswith("socket://") else PtyPort()
        self.url = self._host.url
        self._controller: Optional[DevicePort] = DevicePort(target_url, 115200)
        self._flood: Optional[tuple[list[bytes], float, float]] = None   # frames, bytes/s, start
        self._flood_sent = 0
        self._flood_next = 0
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="line-tap", daemon=True)
        self._thread.start()

    @property
    def to_controller(self) -> bytes:
        """Every whole frame the host sent (forwarded or dropped)."""
        return bytes(self._up.record)

    @property
    def to_host(self) -> bytes:
        """Every whole frame the controller sent."""
        return bytes(self._down.record)

    # ---- the attacker's side (any thread) ----
    def inject_to_controller(self, data: bytes) -> None:
        self._command("to_controller", bytes(data))

    def inject_to_host(self, data: bytes) -> None:
        self._command("to_host", bytes(data))

    def flood(self, frames: list[bytes], bytes_per_s: float) -> None:
        """Replay `frames` in turn towards the controller, `bytes_per_s` on average, until `stop_flood()`."""
        self._command("flood", (list(frames), float(bytes_per_s)))

    def stop_flood(self) -> None:
        self._command("flood", None)

    def retarget(self, url: str) -> None:
        self._command("retarget", url)

    def drop_after(self, msg_id: Optional[int], until: Optional[int] = None) -> None:
        """Pass the host's frames up to the first with `msg_id`, then lose them all up to the first with `until`,
        which passes and ends the loss (None: pass all again). In force when this returns, so the host's next
        frame goes by it."""
        applied = threading.Event()
        self._command("drop_after", (msg_id, until, applied))
        if not applied.wait(10.0):
            raise RuntimeError("the line tap's thread did not take drop_after in 10 s")

    def close(self) -> None:
        self._stop = True
        os.write(self._wake_w, b"x")
        self._thread.join(timeout=5)
        for fd in (self._wake_r, self._wake_w):
            os.close(fd)
        if self._controller is not None:
            self._controller.close()
        self._host.close()

    def _command(self, what: str, arg) -> None:
        self._commands.put((what, arg))
        os.write(self._wake_w, b"x")

    # ---- the thread ----
    def _handle_commands(self) -> None:
        while True:
            try:
                what, arg = self._commands.get_nowait()
            except queue.Empty:
                return
            if what == "to_controller":
                self._up.queue(arg)
                self.injected_bytes += len(arg)
            elif what == "to_host":
                self._down.queue(arg)
            elif what == "flood":
                self._flood = None if arg is None else (arg[0], arg[1], self.clock.now())
                self._flood_sent = self._flood_next = 0
            elif what == "drop_after":
                self._take_from_host()          # what the host sent before this call goes by the old rule
                (self._drop_after, self._drop_until, applied), self.dropping = arg, False
                applied.set()
            elif what == "retarget":
                if self._controller is not None:
                    self._controller.close()
                self._controller = DevicePort(arg, 115200)
                self._down.partial.clear()

    def _flood_step(self) -> None:
        """Inject what the flood owes by now."""
        if self._flood is None:
            return
        frames, rate, start = self._flood
        while self._flood_sent <= (self.clock.now() - start) * rate:
            frame = frames[self._flood_next % len(frames)]
            self._flood_next += 1
            self._flood_sent += len(frame)
            self.injected_bytes += len(frame)
            self._up.queue(frame)

    def _read_controller(self) -> bytes:
        if self._controller is None:
            return b""
        try:
            return self._controller.read(65536)
        except (OSError, serial.SerialException):   # it went away (a restart): wait for `retarget`
            self._controller.close()
            self._controller = None
            return b""

    def _pass_up(self, whole: bytes) -> bytes:
        """What of the host's whole frames goes on to the controller."""
        if self._drop_after is None:
            return whole
        passed = []
        for frame, wire in decoded(whole):
            if self.dropping and frame.msg_id == self._drop_until:
                self._drop_after = self._drop_until = None
                self.dropping = False
            if self.dropping:
                self.frames_dropped += 1
                continue
            passed.append(wire)
            self.dropping = frame.msg_id == self._drop_after
        return b"".join(passed)

    def _take_from_host(self) -> None:
        self._up.queue(self._pass_up(self._up.take_whole(self._host.read(65536))))

    def _run(self) -> None:
        while not self._stop:
            if self._sel.select(POLL_S):
                try:
                    os.read(self._wake_r, 4096)
                except BlockingIOError:
                    pass
            self._handle_commands()
            self._take_from_host()
            self._down.queue(self._down.take_whole(self._read_controller()))
            self._flood_step()
            self._up.write(self._controller)
            self._down.write(self._host)
