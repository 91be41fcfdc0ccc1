"""Fuzzing your own parser with `aspod fuzz` (docs/fuzzing.md, "Your own code").

A settings record parser written by hand, as a user's own code might be, with a real bug: its bounds check is off
by one, so a record one byte short gets past it, and `struct.error` escapes where the parser promises only its own
`SettingsError`. The fuzz target is any object with `one_input(data)` (no `close` needed):

    aspod fuzz examples/fuzz_parser.py:target --runs 20000

finds it within a few hundred executions, shrinks the input to a few bytes, and saves it in fuzz-findings/.
"""
from __future__ import annotations

import struct


class SettingsError(ValueError):
    """A record that is not a setting (the only error `parse_settings` means to raise)."""


def parse_settings(data: bytes) -> dict[str, int]:
    """Records, one after another: a name's length (one byte), the name (ASCII letters and digits), its value (two
    bytes, big-endian)."""
    settings: dict[str, int] = {}
    at = 0
    while at < len(data):
        size = data[at]
        end = at + 1 + size + 2
        if end > len(data) + 1:                 # the bug: should be `end > len(data)`
            raise SettingsError(f"record at byte {at}: needs {end - at} bytes, {len(data) - at} left")
        name = data[at + 1:at + 1 + size]
        if not name.isalnum():
            raise SettingsError(f"record at byte {at}: the name {name!r} is not letters and digits")
        settings[name.decode("ascii")] = struct.unpack_from(">H", data, at + 1 + size)[0]
        at = end
    return settings


class SettingsParserTarget:
    """The parser's promise as an oracle: whatever the bytes, a dict or a SettingsError, nothing else."""

    def one_input(self, data: bytes) -> None:
        try:
            parse_settings(data)
        except SettingsError:
            pass


def target() -> SettingsParserTarget:
    return SettingsParserTarget()
