"""This user's runtime folder: what a live simulator keeps while it runs that only this user may reach (its control
socket, its own key), and where a host looks for them.

The folder is `$XDG_RUNTIME_DIR/aspod`, else `$TMPDIR/aspod-<uid>` (`/tmp` without TMPDIR), mode 0700. Anyone may
take a name in /tmp first: another user making `/tmp/aspod-1000` before user 1000 does once stopped every
`aspod sim` of 1000's. A simulator that finds the folder not its user's, or open to others, says so and makes a
folder of its own (`tempfile.mkdtemp`: `aspod-<uid>-XXXXXXXX` beside it, 0700, a name no one can take first),
which it removes when it stops. A host looks in the first and in each `aspod-<uid>-*` beside it, trusting only
folders of this user's with mode 0700 (`search_folders`), and in them only sockets served by this user
(host_tools/client/control.py).

A simulator without --key-file makes a key of its own here (`new_key`: `sim-<pid>.key`, 0600), removed when it
stops: no two simulators share a key unless told to. A simulator killed with SIGKILL cannot remove its key; the
next one to open the folder removes the keys of processes that are gone.
"""
from __future__ import annotations

import os
import secrets
import stat
import tempfile
from pathlib import Path
from typing import Callable, Mapping, Optional

from protocol import auth

SOCKET_NAME = "sim-{pid}.sock"
KEY_NAME = "sim-{pid}.key"
MAX_FOLDERS = 16          # folders of its own (made because the first was taken) a host looks through
MAX_SWEPT = 256           # key files looked at when a folder is opened


def runtime_dir(environ: Optional[Mapping[str, str]] = None) -> Path:
    """The per-user folder: `$XDG_RUNTIME_DIR/aspod`, else `$TMPDIR/aspod-<uid>` (`/tmp` without TMPDIR)."""
    environ = os.environ if environ is None else environ
    base = environ.get("XDG_RUNTIME_DIR")
    if base and Path(base).is_absolute() and Path(base).is_dir():
        return Path(base) / "aspod"
    return temp_base(environ) / f"aspod-{os.getuid()}"


def temp_base(environ: Mapping[str, str]) -> Path:
    base = environ.get("TMPDIR")
    return Path(base) if base and Path(base).is_absolute() and Path(base).is_dir() else Path("/tmp")


def private_dir(path: Path) -> None:
    """Make `path` (mode 0700) or check it: a folder of this user's that no one else may enter or write. A
    folder of another user's (someone took /tmp/aspod-<uid> first) or open to others is refused: OSError."""
    try:
        path.mkdir(mode=0o700, parents=False)
    except FileExistsError:
        pass
    info = path.lstat()
    if not stat.S_ISDIR(info.st_mode):
        raise OSError(f"{path} is not a folder")
    if info.st_uid != os.getuid():
        raise OSError(f"{path} belongs to user {info.st_uid}, not to this user ({os.getuid()})")
    if info.st_mode & 0o077:
        raise OSError(f"{path} is open to other users (mode {stat.S_IMODE(info.st_mode):o}); it must be 0700")


def is_private(path: Path) -> bool:
    """Whether `path` is a folder (not a link to one) of this user's that no one else may enter or write."""
    try:
        info = path.lstat()
    except OSError:
        return False
    return stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and not info.st_mode & 0o077


def search_folders(environ: Optional[Mapping[str, str]] = None) -> list[Path]:
    """Where this user's simulators keep their sockets: the runtime folder, then the folders simulators made of
    their own beside it (at most MAX_FOLDERS); only those of this user's with mode 0700."""
    environ = os.environ if environ is None else environ
    first = runtime_dir(environ)
    try:
        own = sorted(temp_base(environ).glob(f"aspod-{os.getuid()}-*"))[:MAX_FOLDERS]
    except OSError:
        own = []
    return [folder for folder in [first, *own] if is_private(folder)]


class RuntimeFolder:
    """The private folder one simulator uses (`open`), its key (`new_key`) and control socket (`control_path`) in
    it; `close` removes its key, and the folder too if the simulator made it."""

    def __init__(self, path: Path, made: bool) -> None:
        self.path = path
        self.made = made
        self.key_path: Optional[Path] = None

    @classmethod
    def open(cls, environ: Optional[Mapping[str, str]] = None,
             log: Callable[[str], None] = lambda text: None) -> "RuntimeFolder":
        """The runtime folder, made private if new; if it cannot be used, a folder of its own beside it (said
        through `log`). OSError if neither can be had."""
        environ = os.environ if environ is None else environ
        first = runtime_dir(environ)
        try:
            private_dir(first)
        except OSError as exc:
            try:
                made = Path(tempfile.mkdtemp(prefix=f"aspod-{os.getuid()}-", dir=temp_base(environ)))
            except OSError as again:
                raise OSError(f"no private folder for the simulator's key and control endpoint: {exc}; and "
                              f"{again.strerror or again} making one in {temp_base(environ)}") from None
            log(f"{exc}: using a folder of its own instead, {made} (hosts find it; removed when it stops)")
            return cls(made, made=True)
        folder = cls(first, made=False)
        folder.sweep()
        return folder

    def control_path(self, pid: Optional[int] = None) -> Path:
        return self.path / SOCKET_NAME.format(pid=os.getpid() if pid is None else pid)

    def new_key(self) -> tuple[bytes, Path]:
        """A fresh key of this simulator's own, in a file only this user may read: (key, path)."""
        key = secrets.token_bytes(auth.KEY_BYTES)
        path = self.path / KEY_NAME.format(pid=os.getpid())
        auth.write_key(path, key)
        self.key_path = path
        return key, path

    def sweep(self) -> None:
        """Remove the keys and sockets of simulators that are gone (killed before they could remove their own)."""
        for pattern in (KEY_NAME, SOCKET_NAME):
            for path in sorted(self.path.glob(pattern.format(pid="*")))[:MAX_SWEPT]:
                if not owner_alive(path):
                    try:
                        path.unlink()
                    except OSError:
                        pass

    def close(self) -> None:
        if self.key_path is not None:
            try:
                self.key_path.unlink()
            except FileNotFoundError:
                pass
            self.key_path = None
        if self.made:
            try:
                self.path.rmdir()         # empty by now: its socket and key went first
            except OSError:
                pass


def owner_alive(path: Path) -> bool:
    """Whether the process a `sim-<pid>.key` or `sim-<pid>.sock` names still runs (a name of another shape: yes)."""
    pid = path.name[len("sim-"):].split(".", 1)[0]
    return not pid.isdigit() or process_alive(int(pid))


def process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:           # another user's process
        return True
    return True
