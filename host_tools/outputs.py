"""The files a command writes: claimed before the work starts, then written whole or not at all.

Claiming (`Claims`, when a command's settings are built, before anything runs) refuses, with a
ValueError that names the option and the path (exit 2, as other bad input):

* a path that is an input of the same run (the key file, the parameter file, the script, the
  capture read, ...), by whatever name: another spelling, `..`, a hard link, a symbolic link.
  `--force` does not change this: an output never replaces what the run reads;
* the same path named for two outputs of the run;
* anything but a regular file in its place (a folder, a device, a FIFO, a socket);
* a folder that is not there, or one this process cannot make a file in (found by making one,
  so a read-only file system or a root-owned folder is refused as it would fail), or a
  destination file that is read-only;
* an existing file that holds something, but not what this output writes (its `Kind`, known
  from its first bytes): a capture over a text file, say. `--force` overwrites it.

Writing (`Output.open`, `Pending`): the bytes go to a temporary file beside the destination,
`.NAME.XXXXXXXX.part.SUFFIX`, with the mode the destination has or a new file would get.
`commit` flushes it to the disk and renames it over the destination in one step, so a reader
sees the old file or the whole new one, never half of one. `discard` removes it. `with
output.open() as f:` commits when the block ends and discards when it raises (an error, Ctrl-C,
SIGTERM). A process killed outright (SIGKILL, a power cut) leaves the temporary and the
destination as it was. A live capture stays readable up to its last frame in its temporary
(its writer flushes every frame), so such a leftover can still be read, and renamed by hand.

Folders of outputs (`Claims.folder`: a campaign's, a fuzzer's corpus and findings, a plan's
figures) are checked the same way for inputs and writability, and made when the work starts;
what goes into them is the command's own business.

An appended output (`--log-file`) is claimed the same way and never renamed: each line is
whole when it is written.

A rotated output (`--can-log` with `--can-rotate-mb`) also writes numbered parts beside its destination, each put
in place when it is full (host_tools/worlds/can_log.py). `Claims.series` claims their names, any number of them:
refused, whatever `--force`, if a file of those names is already there (an earlier run's parts, which this run's
would mix with or replace) or is an input or another output of the run. A part is made under a name no file has.
"""
from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable, Iterable, Optional, Union

HEAD_BYTES = 64          # what `Kind.fits` is shown of an existing file


@dataclass(frozen=True)
class Kind:
    """What an output file is. `name` says it in a refusal ("a pcapng capture"); `fits(first_bytes)` says whether
    an existing file already is one (an empty file is of every kind: there is nothing in it to lose); `suffixes`,
    if any, are the names it must end with; `appended`: written by appending, never replaced."""
    name: str
    fits: Callable[[bytes], bool]
    suffixes: tuple[str, ...] = ()
    appended: bool = False


def begins(*heads: bytes) -> Callable[[bytes], bool]:
    """A `Kind.fits` for files that begin with one of `heads`."""
    return lambda first: first.startswith(heads)


PNG = Kind("a PNG image", begins(b"\x89PNG\r\n\x1a\n"), (".png",))
# what `logging.Formatter("%(asctime)s %(levelname)s %(message)s")` writes (host_tools/cli/main.py setup_logging)
LOG_FILE = Kind("a log file of aspod's (lines that begin with a date and a level)",
                lambda first: re.match(rb"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} [A-Z]+ ", first) is not None,
                appended=True)


@dataclass(frozen=True)
class Output:
    """A file a command will write, claimed (`Claims.file`): its path as given, the option that named it, its kind.

    Not a path-like object on purpose: it is written only through `open`, `write_bytes` or `write_text`."""
    path: Path
    option: str
    kind: Kind

    def __str__(self) -> str:
        return str(self.path)

    @property
    def destination(self) -> Path:
        """Where the bytes end up: the path, or the file a symbolic link there points to (as `open` would write)."""
        return Path(os.path.realpath(self.path))

    def open(self, text: bool = False) -> "Pending":
        return Pending(self, text)

    def write_bytes(self, data: bytes) -> None:
        with self.open() as out:
            out.write(data)

    def write_text(self, text: str) -> None:
        with self.open(text=True) as out:
            out.write(text)


def unclaimed(path: Union[Path, str, Output], kind: Kind) -> Output:
    """An `Output` at a path that no command line named (a test's, a library caller's): written the same way,
    not checked."""
    return path if isinstance(path, Output) else Output(Path(path), "", kind)


class Pending:
    """An output being written: `file` (binary, or text with `text`) is a temporary file beside the destination,
    `path`; `commit` puts it in place, `discard` removes it, `keep` leaves it there (a live capture cut short)."""

    def __init__(self, output: Output, text: bool = False) -> None:
        self.output = output
        target = output.destination
        try:
            mode = stat.S_IMODE(os.stat(target).st_mode)
        except FileNotFoundError:
            mode = None
        fd, self.path = _new_file(target.parent, f".{target.name}.", f".part{target.suffix}")
        if mode is not None:
            os.fchmod(fd, mode)
        raw: BinaryIO = os.fdopen(fd, "wb")
        self.file = open(fd, "w", encoding="utf-8", newline="", closefd=False) if text else raw
        self._raw = raw
        self.finished = False

    def commit(self, keep_on_error: bool = False) -> None:
        """Flush to the disk and rename over the destination. An error (a full disk) leaves the destination as it
        was and the temporary removed (with `keep_on_error`, left: a live capture's frames), and is raised."""
        if self.finished:
            return
        try:
            self.file.flush()
            self._raw.flush()
            os.fsync(self._raw.fileno())
            self._close()
            os.replace(self.path, self.output.destination)
        except BaseException:
            self.keep() if keep_on_error else self.discard()
            raise
        self.finished = True

    def discard(self) -> None:
        """Remove the temporary; the destination stays as it was."""
        if self.finished:
            return
        self.finished = True
        self._close()
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass

    def keep(self) -> Path:
        """Close the temporary and leave it where it is, the destination as it was (a live capture whose writing
        failed: what it holds is not lost); returns its path."""
        if not self.finished:
            self.finished = True
            self._close()
        return self.path

    def _close(self) -> None:
        for stream in (self.file, self._raw):
            try:
                stream.close()
            except (OSError, ValueError):     # a full disk on the last flush: what is in the file is what there is
                pass

    def __enter__(self):
        return self.file

    def __exit__(self, kind, value, traceback) -> None:
        if kind is None:
            self.commit()
        else:
            self.discard()


def _new_file(folder: Path, prefix: str, suffix: str) -> tuple[int, Path]:
    """A new file in `folder` with a name no other has, opened for writing with the mode a new file gets (0666 less
    the umask, as `open` would make the destination); OSError if the folder takes none."""
    for _ in range(100):
        path = folder / f"{prefix}{os.urandom(4).hex()}{suffix}"
        try:
            return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666), path
        except FileExistsError:
            continue
    raise FileExistsError(f"no free name for a temporary file in {folder}")


def _same(a: Path, b: Path) -> bool:
    """Whether two paths name one file: by its inode when both are there (hard links too), else by where they
    resolve (symbolic links, `..`)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _kind_of(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _first_bytes(path: Path) -> bytes:
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0))
    try:
        return os.read(fd, HEAD_BYTES)
    finally:
        os.close(fd)


def _can_make_a_file_in(folder: Path) -> Optional[str]:
    """None if a file can be made in `folder` (one is made and removed), else why not."""
    try:
        fd, probe = _new_file(folder, ".aspod-probe-", "")
    except OSError as exc:
        return exc.strerror or str(exc)
    os.close(fd)
    os.unlink(probe)
    return None


class Claims:
    """The outputs of one run, each claimed against the run's inputs, `inputs` ((what it is, path) pairs: "the key
    file (--key-file)"), and against the outputs claimed before it. `force`: overwrite an existing file of another
    kind."""

    def __init__(self, inputs: Iterable[tuple[str, Path]], force: bool = False) -> None:
        self.inputs = [(what, Path(path)) for what, path in inputs]
        self.force = force
        self.claimed: list[tuple[str, Path]] = []
        self.series_claimed: list[tuple[str, Path, "re.Pattern[str]", str]] = []  # option, folder, names, shown

    def _not_taken(self, path: Path, option: str) -> None:
        for what, taken in self.inputs:
            if _same(path, taken):
                raise ValueError(f"{option} {path}: that is {what}, an input of this run, which the output would "
                                 "replace: name another file")
        for other, taken in self.claimed:
            if _same(path, taken):
                raise ValueError(f"{option} {path}: {other} writes there too: name another file")
        real = Path(os.path.realpath(path))
        for other, folder, names, shown in self.series_claimed:
            if real.parent == folder and names.fullmatch(real.name):
                raise ValueError(f"{option} {path}: {other} writes its parts there ({shown}): name another file")

    def file(self, path: Optional[Union[Path, str]], option: str, kind: Kind) -> Optional[Output]:
        """The output at `path` (None: none asked for), or ValueError saying why it may not be written."""
        if path is None:
            return None
        path = Path(path)
        self._not_taken(path, option)
        try:
            info = os.stat(path)
        except FileNotFoundError:
            info = None
        except OSError as exc:
            raise ValueError(f"{option} {path}: {exc.strerror or exc}") from None
        if info is not None and not stat.S_ISREG(info.st_mode):
            raise ValueError(f"{option} {path}: " + ("a folder, not a file" if stat.S_ISDIR(info.st_mode) else
                                                     f"{_kind_of(info.st_mode)}, not a regular file; the output is "
                                                     "written to a file"))
        if kind.suffixes and path.suffix.lower() not in kind.suffixes:
            raise ValueError(f"{option} {path}: it is written as {kind.name}; name it *{' or *'.join(kind.suffixes)}")
        folder = Path(os.path.realpath(path)).parent
        if not folder.is_dir():
            raise ValueError(f"{option} {path}: no folder {path.parent}")
        why = _can_make_a_file_in(folder)
        if why is not None:
            raise ValueError(f"{option} {path}: cannot be written in {path.parent} ({why})")
        if info is not None:
            if not os.access(path, os.W_OK):
                raise ValueError(f"{option} {path}: the file is read-only; it is not replaced")
            if info.st_size and not self.force:
                try:
                    first = _first_bytes(path)
                except OSError as exc:
                    raise ValueError(f"{option} {path}: cannot read what is there ({exc.strerror or exc})") from None
                if not kind.fits(first):
                    raise ValueError(f"{option} {path}: an existing file that is not {kind.name}; --force "
                                     + ("appends to it" if kind.appended else "overwrites it"))
        self.claimed.append((option, path))
        return Output(path, option, kind)

    def series(self, output: Output, names: "re.Pattern[str]", shown: str) -> None:
        """The further files a rotated `output` writes beside its destination: those whose names match `names`
        (`shown` in a refusal: `hal_#NNN.log`), as many as the run makes. ValueError if one is there already, is an
        input of the run or another of its outputs; `--force` does not change this (a run's parts never replace
        another's)."""
        folder = output.destination.parent
        for what, taken in [*((f"{what}, an input of this run", path) for what, path in self.inputs),
                            *((f"where {other} writes", path) for other, path in self.claimed)]:
            real = Path(os.path.realpath(taken))
            if real.parent == folder and names.fullmatch(real.name):
                raise ValueError(f"{output.option} {output.path}: its parts are named {shown}, and {taken} is {what}: "
                                 "name another file")
        try:
            there = sorted(entry.name for entry in os.scandir(folder) if names.fullmatch(entry.name))
        except OSError as exc:
            raise ValueError(f"{output.option} {output.path}: cannot list {folder} ({exc.strerror or exc})") from None
        if there:
            raise ValueError(f"{output.option} {output.path}: its parts are named {shown}, and {folder / there[0]} is "
                             f"there already{f' (and {len(there) - 1} more)' if len(there) > 1 else ''}; parts are "
                             "never replaced, --force or not: move them away or name another file")
        self.series_claimed.append((output.option, folder, names, shown))

    def folder(self, path: Optional[Union[Path, str]], option: str) -> Optional[Path]:
        """A folder of outputs at `path` (made when the work starts, with any missing parents), or ValueError saying
        why it cannot be: not a folder, or its nearest existing folder takes no new file."""
        if path is None:
            return None
        path = Path(path)
        self._not_taken(path, option)
        existing = path
        while not os.path.lexists(existing) and existing != existing.parent:
            existing = existing.parent
        if not existing.is_dir():
            where = "" if existing == path else f" ({existing} is not a folder)"
            raise ValueError(f"{option} {path}: " + ("not a folder" if existing == path else f"cannot be made{where}"))
        why = _can_make_a_file_in(existing)
        if why is not None:
            raise ValueError(f"{option} {path}: " + (f"cannot write in it ({why})" if existing == path
                                                     else f"cannot be made in {existing} ({why})"))
        self.claimed.append((option, path))
        return path
