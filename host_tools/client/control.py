"""The host's end of a live simulator's control endpoint (host_tools/worlds/control_server.py).

`ControlClient(path).request({"op": "fault", "name": "jam", "channel": "j2"})` sends one request
line and returns its reply (`{"ok": ..., ...}`), waiting a bounded time: a step's reply comes
when the step is done, so its wait grows with the step. A refused request is a reply with
`ok` false, not an exception; an endpoint that cannot be reached, or stops answering, raises
`ControlUnavailable` with the reason (and a client that timed out is closed: a late reply would
answer the wrong request). A connection the endpoint closed while it was idle (it yields its slot
to a newcomer when all are taken) is found closed before the next request is sent, and opened
again: a session may hold its client for hours. A request already sent is never sent again: if
the connection ends before its reply, it may have run, and that is said.

`running_simulators()` lists this user's live simulators (`aspod ports`, `aspod teleop` without a URL), and
`find_simulator(url)` finds the endpoint of this user's simulator that serves the link `url`: each
live socket in this user's runtime folders (host_tools/worlds/runtime_folder.py `search_folders`)
answers `info` with its link and the path of the link's key. One registry, two uses:
`find_control(url)`, the endpoint that reaches the plant (an `aspod sim` in one process), and
`simulator_key(url)`, the key of a host tool given no --key-file (every simulator: `aspod sim`,
`aspod sim --hal`, `aspod firmware`). A real controller has neither: its key is given as a file.
`open_control(url, path)` connects to the one given, or else to the one found, if any.

`LockstepBench.control` (the lock-step world) answers the same requests in-process; both have
`request(request) -> dict` and `where`, which is all teleop's `sim` words and the plugin need.
"""
from __future__ import annotations

import json
import os
import select
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Optional

from protocol import auth
from protocol.errors import KeyFileError

from host_tools.worlds.control_server import link_endpoints, peer_uid
from host_tools.worlds.runtime_folder import owner_alive, search_folders

REPLY_TIMEOUT_S = 10.0         # a request's reply (the endpoint answers within a poll, 10 ms, when the world runs)
STEP_WALL_PER_S = 4.0          # ... and a step's, this much wall time more per simulated second (a busy host)
FIND_TIMEOUT_S = 1.0           # `find_simulator`: a socket that does not answer `info` in this is not the one
MAX_REPLY = 1 << 20
MAX_SCANNED = 64               # sockets looked at by `find_simulator`
LINK_KEYS = ("link", "link2")     # what `info` names: the link, and a two-arm simulator's second arm's (its key)


class ControlUnavailable(OSError):
    """The control endpoint cannot be reached, or stopped answering."""


def reply_timeout_s(request: dict) -> float:
    seconds = request.get("seconds") if request.get("op") == "step" else 0.0
    return REPLY_TIMEOUT_S + STEP_WALL_PER_S * (seconds if isinstance(seconds, (int, float)) else 0.0)


class ControlClient:
    """A connection to the control endpoint at `path` (a Unix socket served by this user's `aspod sim`)."""

    def __init__(self, path: Path, connect_timeout_s: float = REPLY_TIMEOUT_S) -> None:
        self.path = Path(path)
        self.where = f"the control endpoint {self.path}"
        self.connect_timeout_s = connect_timeout_s
        self.reconnects = 0            # connections the endpoint closed while idle, opened again
        self._inbox = bytearray()
        self._sock: Optional[socket.socket] = self._connect()

    def _connect(self) -> socket.socket:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.settimeout(self.connect_timeout_s)
            sock.connect(str(self.path))
            uid = peer_uid(sock)
            if uid is not None and uid != os.getuid():
                raise ControlUnavailable(f"{self.where} is served by user {uid}, not by this user ({os.getuid()})")
        except ControlUnavailable:
            sock.close()
            raise
        except OSError as exc:
            sock.close()
            raise ControlUnavailable(f"{self.where}: {exc.strerror or exc} (is its aspod sim still running?)") \
                from None
        return sock

    def _closed_by_endpoint(self) -> bool:
        """Before a request: has the endpoint closed this connection? Between requests it owes nothing, so anything
        readable (its end of file, a reset) means it has."""
        try:
            readable, _, _ = select.select([self._sock], [], [], 0)
        except (OSError, ValueError):
            return True
        return bool(readable)

    def request(self, request: dict, timeout_s: Optional[float] = None) -> dict:
        """Send `request`, return its reply; ControlUnavailable if the endpoint is gone or silent."""
        if self._sock is None:
            raise ControlUnavailable(f"{self.where}: the connection is closed (an earlier request went unanswered, "
                                     "or it could not be opened again)")
        if self._closed_by_endpoint():        # nothing of this request has gone: opening again is safe
            self._sock.close()
            self._sock, self._inbox = None, bytearray()
            self._sock = self._connect()
            self.reconnects += 1
        line = json.dumps(request).encode() + b"\n"
        try:
            self._sock.settimeout(reply_timeout_s(request) if timeout_s is None else timeout_s)
            self._sock.sendall(line)
            return self._reply()
        except socket.timeout:
            self.close()
            raise ControlUnavailable(f"{self.where}: no reply to {request.get('op')!r} in time") from None
        except ControlUnavailable:
            self.close()
            raise
        except OSError as exc:
            self.close()
            raise ControlUnavailable(f"{self.where}: {exc.strerror or exc}") from None

    def _reply(self) -> dict:
        while b"\n" not in self._inbox:
            data = self._sock.recv(65536)
            if not data:
                raise ControlUnavailable(f"{self.where} closed the connection before it answered (its aspod sim "
                                         "stopped?); the request may have run")
            self._inbox += data
            if len(self._inbox) > MAX_REPLY:
                raise ControlUnavailable(f"{self.where} sent a reply longer than {MAX_REPLY} bytes")
        end = self._inbox.index(b"\n")
        line = bytes(self._inbox[:end])
        del self._inbox[:end + 1]
        try:
            reply = json.loads(line)
        except ValueError:
            raise ControlUnavailable(f"{self.where} answered something that is not JSON: {line[:80]!r}") from None
        if not isinstance(reply, dict) or "ok" not in reply:
            raise ControlUnavailable(f"{self.where} answered something that is not a reply: {line[:80]!r}")
        return reply

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> "ControlClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class Found:
    """A live simulator's endpoint: its socket, and what it answered to `info`."""
    path: Path
    info: dict


def running_simulators(environ: Optional[Mapping[str, str]] = None) -> list[Found]:
    """This user's live simulators, each as its endpoint answers `info` (its link, pid, key, whether it reaches a
    plant), in the order of their sockets' names; a socket that does not answer is left out."""
    return [found for found in map(_asked, _sockets(environ)) if found is not None]


def find_simulator(url: str, environ: Optional[Mapping[str, str]] = None,
                   keys: tuple[str, ...] = LINK_KEYS) -> Optional[Found]:
    """The endpoint of this user's live simulator that serves the link `url` (one its `info` names under `keys`:
    by default the first arm's link or a second arm's), or None."""
    wanted = link_endpoints(url)
    for path in _sockets(environ):
        found = _asked(path)
        if found is not None and any(wanted & link_endpoints(str(found.info.get(key, ""))) for key in keys):
            return found
    return None


def _sockets(environ: Optional[Mapping[str, str]]) -> list[Path]:
    """The simulators' sockets in this user's runtime folders (at most MAX_SCANNED), leaving out those whose process
    is gone (a simulator killed outright leaves its socket: 55 of them once kept a live one out of the scan)."""
    candidates: list[Path] = []
    for folder in search_folders(environ):      # this user's, 0700: nothing else in them is to be trusted
        try:
            candidates += [path for path in sorted(folder.glob("sim-*.sock")) if owner_alive(path)]
        except OSError:
            continue
    return candidates[:MAX_SCANNED]


def _asked(path: Path) -> Optional[Found]:
    """What the endpoint at `path` answers to `info`; None if it is dead or does not answer."""
    try:
        with ControlClient(path, FIND_TIMEOUT_S) as control:
            info = control.request({"op": "info"}, FIND_TIMEOUT_S)
    except ControlUnavailable:
        return None                  # a dead simulator's socket, or one that does not answer
    return Found(path, info) if info.get("ok") else None


def find_control(url: str, environ: Optional[Mapping[str, str]] = None) -> Optional[Path]:
    """The control socket of this user's live `aspod sim` that serves the link `url` and reaches its plant, or
    None. Not for a second arm's link (`aspod sim --arms 2`): the endpoint's faults, actions and `state` are the
    first arm's plant's, and a host on the second arm's link would act on the wrong arm."""
    found = find_simulator(url, environ, keys=("link",))
    return found.path if found is not None and found.info.get("plant") is True else None


def simulator_key_file(url: str, environ: Optional[Mapping[str, str]] = None) -> Optional[Path]:
    """The key file of this user's live simulator serving `url`, as its endpoint says, or None."""
    found = find_simulator(url, environ)
    key = found.info.get("key") if found is not None else None
    return Path(key) if isinstance(key, str) and key else None


def simulator_key(url: str, option: str = "--key-file", environ: Optional[Mapping[str, str]] = None) -> bytes:
    """The key of this user's live simulator serving `url`, as its endpoint says; KeyFileError naming `option` and
    what to do when there is none (a real controller, a simulator without its endpoint, or none at all)."""
    key = simulator_key_file(url, environ)
    if key is None:
        raise KeyFileError(f"no {option} given, and no simulator of this user's serving {url} says its key: give "
                           f"{option} FILE (for a simulator, the path on its ASPOD-KEY line; for a real controller, "
                           "its key file); an aspod proxy's address is not its simulator's, and a simulator run "
                           "with --no-control serves no endpoint to find it by")
    return auth.load_key(key, f"the key file of the simulator serving {url}:")


def open_control(url: str, path: Optional[Path] = None) -> Optional[ControlClient]:
    """The control endpoint beside the link `url`: at `path` (ControlUnavailable if it cannot be reached), else
    the one of the aspod sim serving `url`, if any (None: a real controller, or a simulator without one)."""
    if path is not None:
        return ControlClient(path)
    found = find_control(url)
    if found is None:
        return None
    try:
        return ControlClient(found)
    except ControlUnavailable:        # it stopped since it was found
        return None
