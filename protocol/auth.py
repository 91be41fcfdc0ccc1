"""Keys: the pre-shared key file, and the keys derived from it for each direction.

Every frame is signed with HMAC-SHA256 truncated to 16 bytes and carries a 48-bit
counter that must strictly increase in its direction; a receiver checks both before
any state changes and commits the counter only after the tag verifies (as CCSDS SDLS
does), so a forged frame with a huge counter cannot block genuine traffic.

Replays across restarts are defeated by session keys: HELLO carries a fresh host
nonce, HelloReply a fresh controller nonce, and every later frame is signed with
``HMAC(psk, "aspod/v1/session/<direction>" | host_nonce | controller_nonce)``. A frame
recorded in an earlier session does not verify in this one, whichever end restarted.
Keys differ per direction, so a frame reflected back to its sender does not verify.
The handshake frames themselves use a per-direction handshake key; a replayed HELLO
only opens a *pending* session that the controller adopts when a frame signed with
its key arrives, which an attacker without the PSK cannot make.
"""
from __future__ import annotations

import hashlib
import hmac
import os
import secrets
import string
from dataclasses import dataclass
from pathlib import Path

from protocol import files
from protocol.errors import KeyFileError
from protocol.framing import MacKey

KEY_BYTES = 32
KEY_FILE_LIMIT = 4 * files.KIB   # a key is 64 hex digits; room for comment lines, not for a mistaken file
MIN_KEY_BYTES = 16
NONCE_BYTES = 16
CONTROLLER_ID_BYTES = 8
COOKIE_BYTES = 8
COOKIE_LABEL = b"aspod/v1/cookie"   # hello_cookie: HMAC(secret, COOKIE_LABEL | host_nonce | slot as i64 LE)
TO_CONTROLLER = b"h2c"
TO_HOST = b"c2h"


def _derive(psk: bytes, label: bytes) -> bytes:
    return hmac.digest(psk, b"aspod/v1/" + label, "sha256")


@dataclass(frozen=True)
class DirectionKeys:
    """The pair of keys one end uses: one to sign what it sends, one to verify what it receives."""

    tx: MacKey
    rx: MacKey


def handshake_keys(psk: bytes, is_controller: bool) -> DirectionKeys:
    h2c = _derive(psk, b"handshake/" + TO_CONTROLLER)
    c2h = _derive(psk, b"handshake/" + TO_HOST)
    c2h, h2c = MacKey(c2h), MacKey(h2c)
    return DirectionKeys(tx=c2h, rx=h2c) if is_controller else DirectionKeys(tx=h2c, rx=c2h)


def session_keys(psk: bytes, host_nonce: bytes, controller_nonce: bytes, is_controller: bool) -> DirectionKeys:
    nonces = host_nonce + controller_nonce
    h2c = _derive(psk, b"session/" + TO_CONTROLLER + nonces)
    c2h = _derive(psk, b"session/" + TO_HOST + nonces)
    c2h, h2c = MacKey(c2h), MacKey(h2c)
    return DirectionKeys(tx=c2h, rx=h2c) if is_controller else DirectionKeys(tx=h2c, rx=c2h)


def nak_key(psk: bytes, controller_id: bytes) -> MacKey:
    """The key a controller signs its handshake NAKs with (`Nak(NO_SESSION)` and friends, sent with no session):
    bound to its identity, so that a host believes only its own session's controller when it says it has no
    session. Another controller holding the same key answers under another identity, whose NAKs do not verify."""
    return MacKey(_derive(psk, b"nak/" + TO_HOST + controller_id))


def hello_cookie(secret: bytes, host_nonce: bytes, epoch: int) -> bytes:
    """The cookie a controller gives a Hello's nonce in time slot `epoch`: an HMAC under a secret of its own, so it
    keeps no state for the Hellos it has only answered with a cookie (as TCP's SYN cookies, DTLS's
    HelloVerifyRequest, RFC 6347 4.2.1, and IKEv2's COOKIE, RFC 7296 2.6)."""
    return hmac.digest(secret, COOKIE_LABEL + host_nonce + epoch.to_bytes(8, "little", signed=True), "sha256")[:COOKIE_BYTES]


def new_nonce() -> bytes:
    return secrets.token_bytes(NONCE_BYTES)


KEY_RULE = (f"a key is an even number of hex digits, at least {2 * MIN_KEY_BYTES} ({MIN_KEY_BYTES} bytes; `aspod key "
            f"new` writes {2 * KEY_BYTES}), whitespace and lines' `#` comments aside")


def parse_key(text: str, source: str) -> bytes:
    """A key written as hex (whitespace and `#` comments ignored); KeyFileError saying what is wrong and the rule."""
    lines = [line.split("#", 1)[0] for line in text.splitlines()]
    digits = "".join("".join(lines).split())
    bad = next((c for c in digits if c not in string.hexdigits), None)
    if bad is not None:
        raise KeyFileError(f"{source}: not a hex key: {bad!r} is not a hex digit; {KEY_RULE}")
    if len(digits) % 2:
        raise KeyFileError(f"{source}: not a hex key: an odd number of hex digits ({len(digits)}); {KEY_RULE}")
    key = bytes.fromhex(digits)
    if len(key) < MIN_KEY_BYTES:
        raise KeyFileError(f"{source}: a key of {len(key)} bytes ({len(digits)} hex digits) is too short; {KEY_RULE}")
    return key


def fingerprint(key: bytes) -> str:
    """A short name of `key` to compare two ends' keys by (16 hex digits of a hash; it tells nothing of the key)."""
    return hashlib.sha256(b"ASPOD key fingerprint\x00" + key).hexdigest()[:16]


def load_key(path: Path | str, what: str = "key file") -> bytes:
    """The key in the file at `path`; KeyFileError naming `what` (e.g. the option, `--key-file`) and the path.

    Read through `files.read_bounded`: a regular file of at most KEY_FILE_LIMIT bytes."""
    source = f"{what} {path}"
    try:
        text = files.read_bounded(path, KEY_FILE_LIMIT).decode("ascii")
    except files.InputFileError as exc:
        raise KeyFileError(f"{what} {exc}") from None
    except UnicodeDecodeError:
        raise KeyFileError(f"{source}: not a hex key (not ASCII text)") from None
    return parse_key(text, source)


def write_key(path: Path | str, key: bytes, replace: bool = True) -> None:
    """Write `key` atomically, readable by its owner only. With `replace` False an existing file is left as it is
    (FileExistsError), also one made meanwhile: the whole key is linked into place, which fails where a file is."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        with os.fdopen(fd, "w", encoding="ascii") as out:
            out.write("# ASPOD link pre-shared key (HMAC-SHA256), hex\n" + key.hex() + "\n")
            out.flush()
            os.fsync(out.fileno())
        if replace:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
