"""Errors of the protocol package, named by phase (as python-can's CanError tree).

Everything the frame finder, frame decoder and payload codec raise on bad input is
a `ParseError`; each carries the `Reason` code the controller answers with.
"""
from __future__ import annotations

from protocol.reasons import Reason


SHOWN_CHARS = 40    # how much of a person's text an error message repeats


def shown(text: str, head: int = SHOWN_CHARS) -> str:
    """`text` quoted for an error message: whole if it is short, else its first `head` characters and its
    length, so that a megabyte typed (or piped) by mistake is not echoed back whole."""
    if len(text) <= head:
        return repr(text)
    return f"{text[:head]!r}... ({len(text)} chars)"


class ProtocolError(Exception):
    """Base of every error this package raises."""


class ParseError(ProtocolError, ValueError):
    """Bytes from the wire that are not a valid frame or payload."""

    def __init__(self, reason: Reason, detail: str) -> None:
        super().__init__(f"{reason.name}: {detail}")
        self.reason = reason
        self.detail = detail


class EncodeError(ProtocolError, ValueError):
    """A message that cannot be put on the wire (a value out of its declared range, say)."""


class LinkError(ProtocolError):
    """The link cannot do what was asked (no session, suspended, closed)."""

    def __init__(self, reason: Reason, detail: str = "") -> None:
        super().__init__(f"{reason.name}: {detail or reason.doc}")
        self.reason = reason


class KeyFileError(ProtocolError, OSError):
    """A key file that is missing, unreadable or not a valid key."""
