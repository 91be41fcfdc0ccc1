"""The HAL bus codec: the frames declared once in `hal.dbc`, as python-can messages.

The DBC file is the single declaration of the bus between the controller
(`firmware_py`) and the plant (`hil_sim`, or real hardware). This module parses it
once with cantools and pre-resolves every message by name and by frame ID, so a
per-tick encode or decode is one dict lookup plus cantools' own work (a few
microseconds).

Decoding is deliberately lenient about *what* arrives and strict about *how*:
a frame whose ID is not declared (or that is an error, remote or 29-bit frame) is
simply not ours and decodes to ``None``; a frame with a declared ID whose length
or values break the declaration raises `HalDecodeError`.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional, Union

import can
import cantools
from cantools.database.can import Database, Message as DbcMessage

DBC_PATH = Path(__file__).with_name("hal.dbc")

SignalValues = dict[str, Union[int, float]]

# Data lengths a CAN FD frame can have (ISO 11898-1:2015, DLC 9..15 -> 12..64 bytes).
FD_LENGTHS = (8, 12, 16, 20, 24, 32, 48, 64)

# Arm channels in the order every per-channel HAL frame lists them (signal suffixes).
ARM_CHANNELS = ("j1", "j2", "j3", "j4", "gripper", "mount")


class HalEncodeError(ValueError):
    """A message that cannot be built: unknown name, missing/unknown signal, value out of range."""


class HalDecodeError(ValueError):
    """A frame with a declared ID whose data does not match its declaration."""


@functools.lru_cache(maxsize=1)
def _default_database() -> Database:
    # Parsed once per process and never mutated; every HalCodec() without a path shares it.
    return cantools.database.load_file(DBC_PATH, database_format="dbc", strict=True)


@dataclass(frozen=True)
class _Spec:
    """One declared message, resolved once."""

    name: str
    frame_id: int
    length: int
    message: DbcMessage
    # (signal, lowest, highest) accepted on decode: the declared range widened by half a count,
    # so that a value saturated at a limit survives the integer round trip.
    checks: tuple[tuple[str, float, float], ...]
    is_fd: bool


class HalCodec:
    """Encode and decode HAL bus frames as declared in one DBC file (default: `hal.dbc`)."""

    def __init__(self, dbc_path: Optional[Union[str, os.PathLike]] = None) -> None:
        if dbc_path is None:
            self.database = _default_database()
        else:
            self.database = cantools.database.load_file(dbc_path, database_format="dbc", strict=True)
        self._by_name: dict[str, _Spec] = {}
        self._by_id: dict[int, _Spec] = {}
        for message in self.database.messages:
            if message.is_extended_frame:
                raise ValueError(f"{message.name}: the HAL bus uses standard 11-bit IDs")
            if message.length not in (FD_LENGTHS if message.is_fd else (8,)):
                raise ValueError(f"{message.name}: a classic frame must be 8 bytes, a CAN FD frame one of "
                                 f"{FD_LENGTHS}; declared {message.length}")
            checks = tuple(
                (s.name, s.minimum - abs(s.scale) / 2, s.maximum + abs(s.scale) / 2)
                for s in message.signals
                if s.minimum is not None and s.maximum is not None
            )
            spec = _Spec(message.name, message.frame_id, message.length, message, checks, message.is_fd)
            self._by_name[spec.name] = spec
            self._by_id[spec.frame_id] = spec

    @property
    def names(self) -> tuple[str, ...]:
        """Declared message names, in frame-ID (priority) order."""
        return tuple(s.name for s in sorted(self._by_name.values(), key=lambda s: s.frame_id))

    def is_fd(self, name: str) -> bool:
        return self._spec(name).is_fd

    def frame_id(self, name: str) -> int:
        return self._spec(name).frame_id

    def limits(self, name: str, signal: str) -> tuple[float, float]:
        """Declared (minimum, maximum) of a signal, in its physical unit."""
        sig = self._spec(name).message.get_signal_by_name(signal)
        return float(sig.minimum), float(sig.maximum)

    def cycle_time_s(self, name: str) -> Optional[float]:
        """Declared send period (DBC attribute GenMsgCycleTime), or None if not declared."""
        cycle_ms = self._spec(name).message.cycle_time
        return cycle_ms / 1000.0 if cycle_ms else None

    def _spec(self, name: str) -> _Spec:
        try:
            return self._by_name[name]
        except KeyError:
            raise HalEncodeError(
                f"no HAL message named {name!r}; declared: {', '.join(self.names)}") from None

    def encode(self, name: str, **signals: Union[int, float]) -> can.Message:
        """Build the frame `name` from physical signal values (every signal is required)."""
        spec = self._spec(name)
        try:
            data = spec.message.encode(signals, scaling=True, padding=False, strict=True)
        except (cantools.database.EncodeError, TypeError, ValueError, OverflowError) as exc:
            raise HalEncodeError(f"cannot encode {name}: {exc}") from exc
        return can.Message(arbitration_id=spec.frame_id, data=data, dlc=spec.length,
                           is_extended_id=False, is_fd=spec.is_fd)

    def decode(self, msg: can.Message) -> Optional[tuple[str, SignalValues]]:
        """Return (message name, physical signal values), or None if the frame is not declared.

        Raises `HalDecodeError` for a declared ID with the wrong length or a value outside
        its declared range. Never raises for an undeclared ID.
        """
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return None
        spec = self._by_id.get(msg.arbitration_id)
        if spec is None:
            return None
        data = msg.data
        if len(data) != spec.length:
            raise HalDecodeError(
                f"{spec.name} (0x{spec.frame_id:03X}): {len(data)} data bytes, declared {spec.length}")
        try:
            values = spec.message.decode(bytes(data), decode_choices=False, scaling=True,
                                         allow_truncated=False, allow_excess=False)
        except cantools.database.DecodeError as exc:
            raise HalDecodeError(f"{spec.name} (0x{spec.frame_id:03X}): {exc}") from exc
        for signal, lowest, highest in spec.checks:
            value = values[signal]
            if not lowest <= value <= highest:
                raise HalDecodeError(
                    f"{spec.name} (0x{spec.frame_id:03X}): {signal}={value} outside its declared range")
        return spec.name, values  # type: ignore[return-value]


class HalEndpoint:
    """One node's end of the HAL bus: never blocks, never raises on what arrives, counts everything.

    `receive()` yields the decoded frames waiting (at most `max_frames_per_poll`, so a
    flooded bus cannot starve a cooperative scheduler; the rest wait for the next call).
    Undeclared IDs and frames that break their declaration are counted in `bad_frames`;
    a `can.CanError` from the bus is counted in `bus_errors`, never raised: a node that
    cannot talk lets the other side's expiry rules take it to the safe state.
    """

    def __init__(self, bus: can.BusABC, codec: Optional[HalCodec] = None, max_frames_per_poll: int = 256) -> None:
        self.bus = bus
        self.codec = codec if codec is not None else HalCodec()
        self.max_frames_per_poll = max_frames_per_poll
        self.frames_received = 0
        self.frames_sent = 0
        self.bad_frames = 0
        self.bus_errors = 0
        self.last_bus_error: Optional[can.CanError] = None

    def receive(self) -> Iterator[tuple[str, SignalValues]]:
        for _ in range(self.max_frames_per_poll):
            try:
                msg = self.bus.recv(timeout=0)
            except can.CanError as exc:
                self._bus_error(exc)
                return
            if msg is None:
                return
            self.frames_received += 1
            try:
                decoded = self.codec.decode(msg)
            except HalDecodeError:
                decoded = None
            if decoded is None:
                self.bad_frames += 1
                continue
            yield decoded

    def send(self, name: str, **signals: Union[int, float]) -> bool:
        """Encode and send one frame; False (and counted) if the bus refused it."""
        try:
            self.bus.send(self.codec.encode(name, **signals), timeout=0)
        except can.CanError as exc:
            self._bus_error(exc)
            return False
        self.frames_sent += 1
        return True

    def _bus_error(self, exc: can.CanError) -> None:
        self.bus_errors += 1
        self.last_bus_error = exc
