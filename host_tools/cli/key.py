"""`aspod key`: the link's pre-shared key, made and compared.

    aspod key new link.key            a new random key, 32 bytes as 64 hex digits, mode 0600
    aspod key fingerprint link.key    16 hex digits that name the key, to compare two ends' keys

`new` never replaces a file that is there (`--force` does, in one step); the key is written whole
or not at all (protocol/auth.py `write_key`). A fingerprint tells nothing of the key: say it on the
phone to whoever runs the other end, rather than the key.
"""
from __future__ import annotations

import argparse
import logging
import secrets
from pathlib import Path

from host_tools.exit_codes import EXIT_OK, EXIT_USAGE
from protocol import auth

log = logging.getLogger("aspod")


def new_key(path: Path, force: bool) -> int:
    key = secrets.token_bytes(auth.KEY_BYTES)
    if path.is_dir():
        log.error(f"aspod key new: {path} is a folder; name the key's file")
        return EXIT_USAGE
    try:
        auth.write_key(path, key, replace=force)
    except FileExistsError:
        log.error(f"aspod key new: {path} exists; a key is never replaced unless --force says so (the ends that "
                  "hold the old one could no longer connect)")
        return EXIT_USAGE
    except OSError as exc:
        log.error(f"aspod key new: cannot write {path}: {exc.strerror}")
        return EXIT_USAGE
    print(f"wrote {path}: a new key, readable by you only (mode 0600); fingerprint {auth.fingerprint(key)}")
    return EXIT_OK


def show_fingerprint(path: Path) -> int:
    key = auth.load_key(path)           # KeyFileError: exit 2, saying what is wrong and the rule (cli/main.py)
    print(f"{auth.fingerprint(key)}  {path}")
    return EXIT_OK


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod key new link.key",
    "aspod key fingerprint link.key",
    "aspod sim --pty --key-file link.key",
]


def add_options(key: argparse.ArgumentParser) -> None:
    actions = key.add_subparsers(dest="action", required=True, metavar="ACTION")
    new = actions.add_parser("new", help="write a new random key (32 bytes, 64 hex digits), mode 0600; an existing "
                                         "file is kept unless --force")
    new.add_argument("file", type=Path, metavar="FILE")
    new.add_argument("--force", action="store_true", default=argparse.SUPPRESS, help="replace FILE if it exists")
    shown = actions.add_parser("fingerprint", help="print 16 hex digits that name the key in FILE (compare two "
                                                   "ends' keys without showing them)")
    shown.add_argument("file", type=Path, metavar="FILE")


def run(args: argparse.Namespace) -> int:
    if args.action == "new":
        return new_key(args.file, getattr(args, "force", False))
    return show_fingerprint(args.file)
