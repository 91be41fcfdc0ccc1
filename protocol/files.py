"""Reading a file a person named on the command line, bounded: the one way every file input is read.

A key file, a parameter file and a teleop script are small regular files. Anything else
named in their place must be refused with a reason, not read: an endless file
(`/dev/zero`, `/dev/urandom`) would be read until memory runs out, a FIFO would hang the
open (or the read) until some other program writes to it, a directory is not text.

`read_bounded(path, limit)` therefore:

* looks at the path first (`os.stat`) and refuses what is not a regular file without
  opening it (opening some devices has effects of its own);
* opens it with O_NONBLOCK (so that a FIFO swapped in meanwhile cannot hang the open) and
  O_NOCTTY, and checks with `fstat` that what it opened is a regular file;
* reads at most `limit + 1` bytes: more than `limit` is refused as too large, whatever
  the file's size said.

`read_stream_bounded(stream, limit)` is the same bound for an already open stream that may
be a pipe (teleop's script on standard input). `open_input(path)` makes the same checks and opens
a regular file of any size to be read in pieces (a session capture, read as a stream).

Errors are `InputFileError` (a ValueError) naming the path and the problem; the caller adds
which option named the file.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO, Callable, Optional, Union

KIB = 1024
MIB = 1024 * KIB

PathLike = Union[str, Path]


class InputFileError(ValueError):
    """A file that cannot serve as the input asked for.

    `missing`: there is no such file (callers with a default use it); `refused`: the path is
    there but is not what an input file may be (not a regular file, or larger than the limit);
    neither: it could not be read (permissions, I/O error).
    """

    def __init__(self, path: PathLike, problem: str, *, missing: bool = False, refused: bool = False) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = str(path)
        self.problem = problem
        self.missing = missing
        self.refused = refused


def size_text(nbytes: int) -> str:
    """`4 KiB`, `256 KiB`, `4 MiB`, `512 bytes`."""
    for unit, size in (("MiB", MIB), ("KiB", KIB)):
        if nbytes >= size and nbytes % size == 0:
            return f"{nbytes // size} {unit}"
    return f"{nbytes} bytes"


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _check_regular(path: PathLike, mode: int) -> None:
    if not stat.S_ISREG(mode):
        raise InputFileError(path, f"{_kind(mode)}, not a regular file", refused=True)


def _too_large(path: PathLike, limit: int) -> InputFileError:
    return InputFileError(path, f"larger than {size_text(limit)}, the most this input may be", refused=True)


def _os_error(path: PathLike, exc: OSError) -> InputFileError:
    return InputFileError(path, f"cannot read it: {exc.strerror or exc}",
                          missing=isinstance(exc, FileNotFoundError))


def _regular_size(path: PathLike) -> int:
    """The size of the regular file `path` (looked at, not opened); else `InputFileError`."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise _os_error(path, exc) from None
    _check_regular(path, info.st_mode)
    return info.st_size


def check_input(path: PathLike, limit: int) -> None:
    """Raise `InputFileError` unless `path` is a regular file of at most `limit` bytes (without opening it)."""
    if _regular_size(path) > limit:
        raise _too_large(path, limit)


def open_input(path: PathLike) -> BinaryIO:
    """The regular file `path` open for reading in pieces, whatever its size (a capture is read as a stream, never
    whole); else `InputFileError`, after the same checks as `read_bounded`."""
    _regular_size(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise _os_error(path, exc) from None
    try:
        _check_regular(path, os.fstat(fd).st_mode)    # what was opened, should the path have changed meanwhile
    except BaseException:
        os.close(fd)
        raise
    return os.fdopen(fd, "rb")


def read_bounded(path: PathLike, limit: int) -> bytes:
    """The bytes of the regular file `path`, at most `limit` of them; else `InputFileError`."""
    check_input(path, limit)
    try:
        with open_input(path) as stream:
            data = _read_at_most(stream.read, limit)
    except OSError as exc:
        raise _os_error(path, exc) from None
    if data is None:
        raise _too_large(path, limit)
    return data


def read_stream_bounded(stream: BinaryIO, limit: int, name: str) -> bytes:
    """At most `limit` bytes from an open binary stream (a pipe, say) to its end; else `InputFileError`."""
    try:
        data = _read_at_most(stream.read, limit)
    except OSError as exc:
        raise _os_error(name, exc) from None
    if data is None:
        raise _too_large(name, limit)
    return data


def _read_at_most(read: Callable[[int], bytes], limit: int) -> Optional[bytes]:
    """Everything `read(n)` gives up to its end, or None once it gives more than `limit` bytes."""
    chunks, total = [], 0
    while total <= limit:
        chunk = read(min(64 * KIB, limit + 1 - total))
        if not chunk:
            return b"".join(chunks)
        chunks.append(chunk)
        total += len(chunk)
    return None
