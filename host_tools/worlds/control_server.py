"""The live simulator's control endpoint: a local Unix socket, served from the scheduler loop, no threads.

`aspod sim` serves `PlantControl` (host_tools/worlds/plant_control.py) here: newline-delimited
JSON requests in, one JSON reply line out for each, in order. A controller whose plant runs in
another process (`aspod firmware`, `aspod sim --hal`) serves `LinkInfo`: `info` only, so that a
host can find its key. `ControlServer.poll` is a task on
the link's wall-clock scheduler (every `POLL_S`): it accepts, reads and writes without blocking,
with bounds everywhere, so no client can stall or swamp the world: at most `MAX_CLIENTS` at
once; when they are all taken, a newcomer displaces the client idle the longest (nothing asked,
nothing owed, for `IDLE_S` at least: idle connections hold a slot only until it is wanted), and
is told so and closed only when every one of them is busy; a request line of at most
`MAX_LINE` bytes (a longer one is answered with an error and its connection closed), at most `MAX_LINES_PER_POLL` requests a
client a poll, and a client's replies held only up to `OUT_HIGH` bytes (past that it is not read
until it reads its replies). A step's reply waits until the step is done; that client's next
requests wait behind it (in the OS's buffer), the others' do not.

Why local-only rather than authenticated like the controller's link: this channel does not
exist on real hardware. It is a test harness's hand on the plant, on the machine that runs the
simulator, and nothing reaches it from the link (a radio, a serial line, a TCP port). Its
authentication is the operating system's: the socket lives in a folder only its user may
enter (host_tools/worlds/runtime_folder.py, mode 0700), the socket itself is 0600, and each
connection's peer is checked with SO_PEERCRED: another user's process is refused. A key would
add nothing a same-user process could not read anyway (the link's key is in that folder too).

Finding it: by default the socket is `sim-<pid>.sock` in the runtime folder, and each live one
answers `info` with the link it sits beside and the path of the link's key. Those sockets are the
one registry: a host given only the link URL looks through them for the control endpoint and for
the key (host_tools/client/control.py `find_simulator`). A socket file whose simulator died is
found dead by connecting to it and replaced; a live one is never touched. The file is removed
when the simulator stops.
"""
from __future__ import annotations

import json
import os
import selectors
import socket
import stat
import struct
from pathlib import Path
from typing import Callable, Optional, Protocol

from host_tools.worlds.plant_control import OPS, Reply, RequestError, decode_request, error_reply

POLL_S = 0.01                  # the link scheduler runs the endpoint this often
MAX_CLIENTS = 8
IDLE_S = 2.0                   # a client silent this long, owed nothing, yields its slot when all are taken
MAX_LINE = 4096                # a request line, its newline excluded: the longest real one is under 100 bytes
READ_CHUNK = 4096
MAX_LINES_PER_POLL = 16        # requests served a client a poll (1,600 a second)
OUT_HIGH = 16 * 1024           # replies held for a client that does not read them: past this it is not read
ACCEPTS_PER_POLL = 16
SUN_PATH_MAX = 107             # bytes of a Unix socket's path (Linux: 108 with its NUL)
CONNECT_TIMEOUT_S = 1.0        # a stale socket refuses at once; a stopped process's may never answer


def is_live(path: Path, timeout_s: float = CONNECT_TIMEOUT_S) -> bool:
    """Whether a process accepts connections on the Unix socket `path` (a dead simulator's file refuses)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        probe.settimeout(timeout_s)
        try:
            probe.connect(str(path))
        except (ConnectionRefusedError, FileNotFoundError):
            return False
        except socket.timeout:
            return True               # a backlog full or a stopped process: not ours to take
        return True


def claim_path(path: Path) -> None:
    """Make `path` free for a new socket: nothing there, or a dead simulator's socket (removed). A live socket, or
    anything that is not a socket, is left alone: OSError saying which."""
    if len(os.fsencode(str(path))) > SUN_PATH_MAX:
        raise OSError(f"control endpoint: {path} is longer than a Unix socket's path may be ({SUN_PATH_MAX} bytes); "
                      "give --control a shorter one")
    try:
        info = path.lstat()
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(info.st_mode):
        raise OSError(f"control endpoint: {path} exists and is not a socket; not replacing it")
    if is_live(path):
        raise OSError(f"control endpoint: a live process serves {path} already (another aspod sim?); give "
                      "--control another path")
    path.unlink()


def peer_uid(sock: socket.socket) -> Optional[int]:
    """The connecting process's user id (SO_PEERCRED), or None where the OS does not say."""
    option = getattr(socket, "SO_PEERCRED", None)
    if option is None:
        return None
    _pid, uid, _gid = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, option, struct.calcsize("3i")))
    return uid


def link_endpoints(url: str) -> set[str]:
    """The endpoints a link URL names: `/dev/pts/5`; several comma-separated, each maybe `name=endpoint`."""
    found = set()
    for part in url.split(","):
        name, sep, endpoint = part.partition("=")
        endpoint = (endpoint if sep and name.isidentifier() else part).strip()
        if endpoint.startswith("/"):
            endpoint = os.path.realpath(endpoint)
        if endpoint:
            found.add(endpoint)
    return found


class Handler(Protocol):
    """What the endpoint serves: one request line in, its reply (now, or when done)."""

    def handle_line(self, line: bytes) -> Reply: ...


class LinkInfo:
    """The endpoint of a controller whose plant is in another process (`aspod firmware`, `aspod sim --hal`): it
    answers `info` (`about`: the link, its key, the process) and refuses the plant's requests, saying why."""

    def __init__(self, about: dict, plant_where: str) -> None:
        self.about = dict(about)
        self.plant_where = plant_where

    def handle_line(self, line: bytes) -> Reply:
        try:
            request = decode_request(line)
        except RequestError as exc:
            return Reply(error_reply(str(exc)))
        op = request.get("op") if isinstance(request, dict) else None
        if op == "info" and request == {"op": "info"}:
            return Reply({"ok": True, "said": "a controller's endpoint; its plant is " + self.plant_where,
                          **self.about, "plant": False, "ops": ["info"]})
        if op in OPS:
            return Reply(error_reply(f"{op}: no plant here to reach: it is {self.plant_where}"))
        return Reply(error_reply(f"unknown op {str(op)[:40]!r}: this endpoint answers only info"))


class _Client:
    """One connection: what it sent that is not yet a whole line, its replies not yet sent, a reply to come."""

    def __init__(self, sock: socket.socket, now: float) -> None:
        self.sock = sock
        self.active_s = now         # when it last sent something or was last answered
        self.inbox = bytearray()
        self.outbox = bytearray()
        self.pending: Optional[Reply] = None
        self.ended = False          # it sent end of file: what it sent whole is still answered
        self.closing = False        # nothing more is read or answered: closed once its replies are out
        self.gone = False           # to be dropped now

    def idle_s(self, now: float) -> float:
        """How long it has asked nothing and been owed nothing (0 while a request of its is under way)."""
        if self.pending is not None or self.inbox or self.outbox or self.closing or self.gone:
            return 0.0
        return now - self.active_s


class ControlServer:
    """`control` (a `PlantControl`, or `LinkInfo`) served on the Unix socket `path` (made free with `claim_path`;
    0600). Add `poll` to a wall-clock scheduler; `close` ends every connection and removes the socket file. `log`
    says what a person should know (a refused peer, a client that sent too much)."""

    def __init__(self, path: Path, control: Handler, *, log: Callable[[str], None] = lambda text: None,
                 max_clients: int = MAX_CLIENTS, max_line: int = MAX_LINE) -> None:
        self.path = Path(path)
        self.control = control
        self.log = log
        self.max_clients = max_clients
        self.max_line = max_line
        self.clients: list[_Client] = []
        claim_path(self.path)
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            try:
                self._listener.bind(str(self.path))
            except OSError as exc:
                raise OSError(f"control endpoint: cannot make the socket {self.path}: {exc.strerror or exc}") from None
            os.chmod(self.path, 0o600)
            self._inode = self.path.lstat().st_ino
            self._listener.listen(max_clients)
            self._listener.setblocking(False)
        except BaseException:
            self._listener.close()
            raise
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ)

    # ---- the task ----
    def poll(self, now: float) -> float:
        """Accept, read, answer, write: whatever can be done now without waiting. Returns its next wake time."""
        readable = {key.fileobj for key, _ in self._selector.select(0)}
        if self._listener in readable:
            self._accept(now)
        for client in self.clients:
            if client.sock in readable or client.pending is not None or client.inbox or client.outbox:
                self._serve(client, client.sock in readable, now)
        if any(c.gone for c in self.clients):
            for client in [c for c in self.clients if c.gone]:
                self._drop(client)
        return now + POLL_S

    def _accept(self, now: float) -> None:
        for _ in range(ACCEPTS_PER_POLL):
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:              # out of descriptors, say: the next poll tries again
                self.log(f"control: could not accept a connection: {exc}")
                return
            sock.setblocking(False)
            uid = peer_uid(sock)
            if uid is not None and uid != os.getuid():
                self.log(f"control: refused a connection from user {uid} (only this user, {os.getuid()}, may)")
                sock.close()
                continue
            if len(self.clients) >= self.max_clients and not self._displace_idle(now):
                self._send_now(sock, error_reply(f"too many control clients ({self.max_clients}), all busy: try "
                                                 "again later"))
                sock.close()
                continue
            self.clients.append(_Client(sock, now))
            self._selector.register(sock, selectors.EVENT_READ)

    def _displace_idle(self, now: float) -> bool:
        """Close the client idle the longest, if one has been for IDLE_S, to make room; whether one was. Its next
        request finds the connection closed before it sends anything (`ControlClient` then reconnects)."""
        idlest = max(self.clients, key=lambda c: c.idle_s(now))
        idle_s = idlest.idle_s(now)
        if idle_s < IDLE_S:
            return False
        self._drop(idlest)
        self.log(f"control: closed a client idle for {idle_s:.0f} s to make room for a new one")
        return True

    def _serve(self, client: _Client, readable: bool, now: float) -> None:
        if client.pending is not None:
            body = client.pending.poll()
            if body is not None:
                client.pending = None
                self._queue(client, body)
        if readable and not (client.ended or client.closing) and b"\n" not in client.inbox \
                and len(client.outbox) < OUT_HIGH:
            self._read(client)
            client.active_s = now
        served = 0
        while client.pending is None and not client.closing and served < MAX_LINES_PER_POLL \
                and len(client.outbox) < OUT_HIGH:
            end = client.inbox.find(b"\n")
            if end < 0:
                if len(client.inbox) > self.max_line:
                    self._too_long(client)
                break
            line = bytes(client.inbox[:end])
            del client.inbox[:end + 1]
            if len(line) > self.max_line:
                self._too_long(client)
                break
            served += 1
            self._answer(client, line)
        if client.ended and client.pending is None and b"\n" not in client.inbox:
            client.closing = True
        if client.outbox:
            client.active_s = now
        self._write(client)
        if client.closing and not client.outbox:
            client.gone = True

    def _read(self, client: _Client) -> None:
        try:
            data = client.sock.recv(READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            client.gone = True
            return
        if not data:                      # end of file: a last line without its newline is not a request
            client.ended = True
            return
        client.inbox += data

    def _answer(self, client: _Client, line: bytes) -> None:
        if not line.strip():
            return
        try:
            reply = self.control.handle_line(line)
            body = reply.poll()
        except Exception as exc:          # a bug here must not stop the simulator: said, and answered
            self.log(f"control: internal error on {line[:80]!r}: {exc!r}")
            reply, body = None, error_reply(f"internal error: {exc!r}")
        if body is None:
            client.pending = reply
        else:
            self._queue(client, body)

    def _too_long(self, client: _Client) -> None:
        self._queue(client, error_reply(f"a request line is at most {self.max_line} bytes; closing"))
        client.inbox.clear()
        client.closing = True
        self.log(f"control: a client sent a line longer than {self.max_line} bytes; closed it")

    @staticmethod
    def _queue(client: _Client, body: dict) -> None:
        client.outbox += json.dumps(body).encode() + b"\n"

    def _write(self, client: _Client) -> None:
        if not client.outbox or client.gone:
            return
        try:
            sent = client.sock.send(client.outbox)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            client.gone = True
            return
        del client.outbox[:sent]

    @staticmethod
    def _send_now(sock: socket.socket, body: dict) -> None:
        try:
            sock.send(json.dumps(body).encode() + b"\n")
        except OSError:
            pass

    def _drop(self, client: _Client) -> None:
        self.clients.remove(client)
        self._selector.unregister(client.sock)
        client.sock.close()

    def close(self) -> None:
        for client in list(self.clients):
            self._drop(client)
        self._selector.close()
        self._listener.close()
        try:
            if self.path.lstat().st_ino == self._inode:     # still ours (not a newer simulator's)
                self.path.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            self.log(f"control: could not remove {self.path}: {exc}")
