"""The in-process fuzz targets: one entry point each, `one_input(data)`, and the oracles that judge it.

A target raises `OracleFailure` when an oracle sees a wrong answer; any other exception that escapes is a crash
(the code under test promised to raise nothing, or only its own errors, and the target catches exactly those).
Targets that keep a world between inputs (`stateful`) are rebuilt every `fresh_every` inputs, so a failure can
be reproduced by replaying at most that many inputs on a fresh target (host_tools/fuzz/findings.py).

    frames           protocol/framing.py: the frame finder and FrameReceiver, over bytes as they come or
                     frames the target completes (CRC, COBS) so the header checks are reached
    codec            protocol/schema.py: every message's decode and encode, judged against the declaration
    controller-link  the controller's link endpoint with a live session and its real handlers (link_targets.py)
    host-link        the host's link endpoint with a live session (link_targets.py)
    hal              the HAL bus decoders at both ends: the controller's (firmware_py/hal.py) and the plant's
    params-file      the controller's parameter file loader (firmware_py/params.py)
    key-file         the key file loader (protocol/auth.py)
    teleop           teleop's line parser and script checker (host_tools/teleop/words.py)

Your own code: `aspod fuzz module:factory` loads any object with `one_input(data)`; `close` is optional (see
docs/fuzzing.md).
"""
from __future__ import annotations

import importlib
import json
import math
import tempfile
from pathlib import Path
from typing import Any, Callable, Optional

from protocol import auth, files
from protocol.errors import EncodeError, KeyFileError, ParseError
from protocol.framing import HEADER, MAX_ENCODED, MAX_PAYLOAD, Frame, FrameReceiver, seal
from protocol.messages import SCHEMA
from protocol.schema import MessageSpec

from host_tools.fuzz.own import own_module
from host_tools.fuzz.grammar import Draw, FdpDraw, draw_payload, draw_value
from host_tools.fuzz.oracles import payload_violation


class OracleFailure(AssertionError):
    """An oracle saw a wrong answer: `oracle` names which, the message says what was seen."""

    def __init__(self, oracle: str, detail: str) -> None:
        super().__init__(f"{oracle}: {detail}")
        self.oracle = oracle


def check(condition: bool, oracle: str, detail: Callable[[], str]) -> None:
    if not condition:
        raise OracleFailure(oracle, detail())


class Target:
    """What every target is: a name, a line of what it covers, `one_input`, and for a stateful one `fresh`."""

    name = ""
    about = ""
    stateful = False
    fresh_every = 1          # inputs between two fresh starts (stateful targets)
    covers: tuple[str, ...] = ()   # source files whose line coverage the campaign reports
    engine_options: tuple[str, ...] = ()   # libFuzzer options this target runs with (host_tools/fuzz/child.py)

    def fresh(self) -> None:
        """Start again from nothing (a stateful target's world built anew)."""

    def one_input(self, data: bytes) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Release what `fresh` built (files, worlds)."""


# ---- frames ----
class FramesTarget(Target):
    """Bytes as they come, or frames sealed by the target (CRC, COBS) so that the header's checks are reached.

    Oracles: `feed` raises nothing and returns only frames and ParseErrors; the receiver keeps at most one
    frame's worth; the frames found do not depend on how the bytes were cut into reads.
    """

    name = "frames"
    about = "the frame finder and receiver (protocol/framing.py), raw bytes and CRC-correct frames"
    covers = ("protocol/framing.py",)

    def one_input(self, data: bytes) -> None:
        draw = FdpDraw(data)
        wire = bytearray()
        for _ in range(1 + draw.pick(4)):
            if draw.pick(2):
                wire += draw.raw(MAX_ENCODED + 8)
            else:          # a header with any values, the right or a wrong length, completed with its CRC
                body = draw.raw(HEADER.size + 6 + MAX_PAYLOAD + 16 + 8)
                wire += seal(body)
        wire = bytes(wire)
        cuts = sorted({draw.pick(len(wire) + 1) for _ in range(draw.pick(6))})
        whole, pieces = FrameReceiver(), FrameReceiver()
        seen_whole = whole.feed(wire)
        seen_pieces = []
        for start, end in zip([0] + cuts, cuts + [len(wire)]):
            seen_pieces += pieces.feed(wire[start:end])
            check(pieces.buffered <= MAX_ENCODED, "bounded", lambda: f"{pieces.buffered} bytes kept")
        for item in seen_whole + seen_pieces:
            check(isinstance(item, (Frame, ParseError)), "only own errors", lambda: f"feed gave {item!r}")
        frames_whole = [f for f in seen_whole if isinstance(f, Frame)]
        frames_pieces = [f for f in seen_pieces if isinstance(f, Frame)]
        check(frames_whole == frames_pieces, "cut-invariant",
              lambda: f"{len(frames_whole)} frames read whole, {len(frames_pieces)} read in {len(cuts) + 1} pieces")


# ---- codec ----
_SPECS = tuple(sorted(SCHEMA.by_id.values(), key=lambda s: s.id))


class CodecTarget(Target):
    """Every message, both ways. Decode: only ParseError; a payload decodes exactly when the declaration allows it
    (`oracles.payload_violation`, its own decoding: a decoder and an encoder that both accept one past a declared
    maximum round-trip, so the round trip alone cannot see it); what decodes encodes back to the same bytes.
    Encode (values from the grammar, any type's): only EncodeError; what encodes is a payload the declaration
    allows, and decodes to the same message."""

    name = "codec"
    about = "every message's decode and encode (protocol/schema.py), payloads from the grammar or any bytes"
    covers = ("protocol/schema.py",)

    def __init__(self, decode: Optional[Callable[[Any, bytes], Any]] = None,
                 specs: tuple[MessageSpec, ...] = _SPECS) -> None:
        self.decode = decode if decode is not None else (lambda spec, payload: spec.decode(payload))
        self.specs = specs

    def one_input(self, data: bytes) -> None:
        draw = FdpDraw(data)
        spec = self.specs[draw.pick(len(self.specs))]
        if draw.pick(2):
            payload = draw_payload(spec, draw)
            refused = payload_violation(spec, payload)
            try:
                msg = self.decode(spec, payload)
            except ParseError as exc:
                why = str(exc)
                check(refused is not None, "decodes as declared",
                      lambda: f"{spec.name}: {payload.hex()} refused ({why}), which the declaration allows")
                return
            again = spec.encode(msg)
            check(again == payload, "round trip",
                  lambda: f"{spec.name}: {payload.hex()} decoded, encoded back as {again.hex()}")
            check(refused is None, "decodes as declared", lambda: f"{spec.name}: {payload.hex()} decoded: {refused}")
            return
        values = [draw_value(f, draw) for f in spec.fields]
        if draw.pick(4) == 0 and values:       # a value of the wrong type
            values[draw.pick(len(values))] = [None, "x", b"x", 1.5, -1, 2**70][draw.pick(6)]
        try:
            msg = spec.type(*values)
            payload = spec.encode(msg)
        except (EncodeError, TypeError):
            return
        refused = payload_violation(spec, payload)
        check(refused is None, "encodes as declared", lambda: f"{spec.name}: {msg!r} encoded: {refused}")
        back = self.decode(spec, payload)      # what encode accepts decode accepts: a ParseError here is a finding
        check(spec.encode(back) == payload, "round trip", lambda: f"{spec.name}: {msg!r} came back as {back!r}")


# ---- files ----
class _FileTarget(Target):
    """A loader that reads a real file: the input is written to one first."""

    stateful = False

    def __init__(self) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="aspod-fuzz-")
        self.path = Path(self._dir.name) / "input"

    def write(self, data: bytes) -> Path:
        self.path.write_bytes(data)
        return self.path

    def close(self) -> None:
        self._dir.cleanup()


class ParamsFileTarget(_FileTarget):
    """The controller's parameter file. Oracles: `load` raises nothing; every value ends inside its range; a
    file refused as a whole leaves every default; a value refused keeps its default; what a file says and
    is accepted is what the store holds."""

    name = "params-file"
    about = "the controller's parameter file loader (firmware_py/params.py), JSON from the grammar or any bytes"
    covers = ("firmware_py/params.py", "protocol/files.py")

    def __init__(self) -> None:
        super().__init__()
        from firmware_py.controller import ControllerConfig, parameter_table
        self.specs = parameter_table(ControllerConfig())

    def _document(self, draw: Draw) -> bytes:
        if draw.pick(4) == 0:
            return draw.raw(4096)
        params: dict[str, Any] = {}
        for _ in range(draw.pick(8)):
            spec = self.specs[draw.pick(len(self.specs))]
            name = spec.name if draw.pick(6) else draw.raw(12).decode("latin-1")
            values = [spec.lo, spec.hi, spec.default, spec.lo - 1, spec.hi * 2 + 1, math.nan, math.inf, "1",
                      True, None, [1], draw.any_float()]
            params[name] = values[draw.pick(len(values))]
        doc: Any = {"version": [1, 1, 1, 2, "1"][draw.pick(5)], "params": params}
        if draw.pick(8) == 0:
            doc = [doc] if draw.pick(2) else {"version": 1, "params": [1]}
        return json.dumps(doc, allow_nan=True).encode()

    def one_input(self, data: bytes) -> None:
        from firmware_py.params import ParamStore
        draw = FdpDraw(data)
        path = self.write(self._document(draw))
        store = ParamStore(self.specs, path)
        defaults = store.values()
        problems = store.load()
        for spec in self.specs:
            value = store[spec.name]
            check(math.isfinite(value) and spec.lo <= value <= spec.hi, "in range",
                  lambda: f"{spec.name}={value} after loading")
        if any("keep their defaults" in p for p in problems):
            check(store.values() == defaults, "refused changes nothing", lambda: "a refused file changed values")
        try:
            said = json.loads(path.read_bytes()).get("params", {})
        except (ValueError, AttributeError, UnicodeDecodeError, RecursionError):
            return
        if not isinstance(said, dict) or problems:
            return
        for name, value in said.items():
            check(store[name] == float(value), "loaded as said", lambda: f"{name}: file {value}, store {store[name]}")


class KeyFileTarget(_FileTarget):
    """The key file. Oracles: only KeyFileError (or the file reader's own error); a key it accepts is at least
    MIN_KEY_BYTES and is exactly the hex digits of the file's non-comment text."""

    name = "key-file"
    about = "the key file loader (protocol/auth.py), hex with comments from the grammar or any bytes"
    covers = ("protocol/auth.py", "protocol/files.py")

    def one_input(self, data: bytes) -> None:
        draw = FdpDraw(data)
        if draw.pick(3) == 0:
            text = draw.raw(auth.KEY_FILE_LIMIT + 16)
        else:
            parts = []
            for _ in range(draw.pick(6)):
                kind = draw.pick(4)
                parts.append(draw.raw(40).hex() if kind == 0 else "# " + draw.raw(20).decode("latin-1")
                             if kind == 1 else [" ", "\n", "\t", "\r\n", "0x", "g", "#"][draw.pick(7)]
                             if kind == 2 else draw.raw(8).decode("latin-1"))
            text = "".join(parts).encode("utf-8", "surrogateescape")
        path = self.write(text)
        try:
            key = auth.load_key(path)
        except (KeyFileError, files.InputFileError):
            return
        check(len(key) >= auth.MIN_KEY_BYTES, "long enough", lambda: f"a {len(key)}-byte key accepted")
        digits = "".join(line.split("#", 1)[0] for line in text.decode("utf-8", "replace").splitlines())
        check(key == bytes.fromhex("".join(digits.split())), "as written", lambda: f"key {key.hex()} from {text!r}")


# ---- teleop ----
class TeleopTarget(Target):
    """Teleop's parser. Oracles: only TeleopError; a line it accepts that sends a command builds a message the
    codec encodes (teleop never hands the link what the link would refuse)."""

    name = "teleop"
    about = "teleop's line parser and script checker (host_tools/teleop/words.py), words from the declaration"
    covers = ("host_tools/teleop/words.py", "host_tools/teleop/sim_words.py")

    def __init__(self) -> None:
        from host_tools.teleop import sim_words, words
        from host_tools.worlds.plant_control import OPS
        from hil_sim.faults import FAULT_NAMES
        from protocol.states import ARM_CHANNELS
        self.words = words
        # the `sim` words' own vocabulary, from their declaration: without it a `sim` line never named an op, and
        # its arguments' parsing went unfuzzed (sim_words.py 30.5 % after 10^7 executions)
        sim_vocabulary = (list(OPS) + list(FAULT_NAMES) + list(ARM_CHANNELS) + list(sim_words.SWITCH_WORDS)
                          + [sim_words.NULL_WORD] + [c for op in OPS.values() for a in op.args for c in a.choices])
        self.vocabulary = list(words._ALL_WORDS) + sim_vocabulary + [
            "j1", "j2", "mount", "all", "az", "el", "both", "open", "close", "on", "off", "now", "aligned",
            "2000-01-01T00:00", "1e39", "nan", "-inf", "0x10", "'", '"', "\\", "#", "${X}", "--", "ok"]

    def _line(self, draw: Draw) -> str:
        if draw.pick(4) == 0:
            return draw.raw(300).decode("latin-1")
        out = []
        for _ in range(1 + draw.pick(6)):
            if draw.pick(3):
                out.append(self.vocabulary[draw.pick(len(self.vocabulary))])
            else:
                out.append(str(draw.any_float()) if draw.pick(2) else str(draw.int_in(-2**40, 2**40)))
        return " ".join(out)

    def one_input(self, data: bytes) -> None:
        draw = FdpDraw(data)
        lines = [self._line(draw) for _ in range(1 + draw.pick(3))]
        for number, line in enumerate(lines, 1):
            try:
                step = self.words.parse_line(line, number)
            except self.words.TeleopError:
                continue
            if step is not None and step.message is not None:
                msg = step.message
                try:
                    msg.spec.encode(msg)
                except EncodeError as exc:
                    raise OracleFailure("teleop builds valid messages", f"{line!r} built {msg!r}: {exc}") from None
        self.words.check_script(lines)


# ---- HAL bus decoders ----
class HalTarget(Target):
    """CAN frames of any declared (or undeclared) id and any bytes into the controller's HAL end and the
    plant's. Oracles: `poll` raises nothing; every frame is read and counted, at most once as bad; the
    controller's inputs are never infinite (NaN until first read)."""

    name = "hal"
    about = "the HAL bus decoders at both ends (firmware_py/hal.py, hil_sim/hal_node.py; protocol/hal.py)"
    covers = ("protocol/hal.py", "firmware_py/hal.py", "hil_sim/hal_node.py")
    stateful = True
    fresh_every = 5000

    def fresh(self) -> None:
        import can
        from firmware_py.hal import ControllerHal
        from host_tools.worlds.local_bus import LocalBus, LocalChannel
        from host_tools.worlds.nodes import build_plant_node
        from host_tools.worlds.settings import PlantSettings
        self.close()
        channel = LocalChannel()
        self._buses = [LocalBus(channel) for _ in range(3)]
        self.feeder, controller_bus, plant_bus = self._buses
        self.controller = ControllerHal(controller_bus)
        self.plant = build_plant_node(plant_bus, 0, settings=PlantSettings(tracker=True))
        codec = self.controller.codec
        self.ids = sorted(codec.frame_id(name) for name in codec.names) + [0x7FF, 0x000, 0x1FFFFFFF]
        self.can = can
        self.now = 0.0

    def one_input(self, data: bytes) -> None:
        draw = FdpDraw(data)
        sent = 0
        for _ in range(1 + draw.pick(8)):
            frame_id = self.ids[draw.pick(len(self.ids))]
            payload = draw.raw(8 if draw.pick(4) else 64)
            msg = self.can.Message(arbitration_id=frame_id, data=payload, is_extended_id=frame_id > 0x7FF
                                   or draw.pick(8) == 0, is_remote_frame=draw.pick(16) == 0, is_fd=len(payload) > 8)
            self.feeder.send(msg)
            sent += 1
        self.now += 0.001
        for node in (self.controller, self.plant):
            received, bad = node.frames_received, node.bad_frames
            read = node.poll(self.now)
            check(read == sent and node.frames_received - received == sent and 0 <= node.bad_frames - bad <= sent,
                  "every frame counted", lambda: f"{sent} sent, {read} read, {node.frames_received - received} "
                                                 f"counted received, {node.bad_frames - bad} bad")
        inputs = self.controller.inputs
        for name in ("supply_v", "temp_c"):
            value = getattr(inputs, name)
            check(not math.isinf(value), "finite inputs", lambda: f"{name}={value}")   # NaN: not read yet

    def close(self) -> None:
        for bus in getattr(self, "_buses", ()):
            bus.shutdown()
        self._buses = []


def builtin_targets() -> dict[str, Callable[[], Target]]:
    from host_tools.fuzz.link_targets import ControllerLinkTarget, HostLinkTarget
    return {t.name: t for t in (FramesTarget, CodecTarget, ControllerLinkTarget, HostLinkTarget, HalTarget,
                                ParamsFileTarget, KeyFileTarget, TeleopTarget)}


def load_target(spec: str) -> Target:
    """A built-in target by name, or `module:factory` or `file.py:factory` (a callable returning an object with
    `one_input`)."""
    if ":" not in spec:
        factory = builtin_targets().get(spec)
        if factory is None:
            raise ValueError(f"no fuzz target {spec!r}; the targets are {', '.join(builtin_targets())}, "
                             f"or module:factory for your own")
        return factory()
    module_name, attr = own_module(spec), spec.rpartition(":")[2]
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError, TypeError, ValueError) as exc:     # TypeError: ".x", a relative name
        raise ValueError(f"fuzz target {spec}: cannot load it ({exc})") from None
    if not callable(factory):
        raise ValueError(f"fuzz target {spec}: {attr} is not a factory (a callable returning a target)")
    try:
        target = factory()
    except (Exception, SystemExit) as exc:      # noqa: BLE001 (the user's factory: whatever it raises is refused)
        raise ValueError(f"fuzz target {spec}: its factory raised {type(exc).__name__}: {exc}") from None
    if not callable(getattr(target, "one_input", None)):
        raise ValueError(f"fuzz target {spec}: {target!r} has no one_input(data)")
    return target if callable(getattr(target, "close", None)) else _Closable(target)


class _Closable:
    """Your own target with no `close` (it is optional): the target itself in every other respect."""

    def __init__(self, target: Any) -> None:
        self.__dict__["_target"] = target

    def __getattr__(self, name: str) -> Any:
        return getattr(self._target, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self._target, name, value)

    def close(self) -> None:
        """Nothing to release."""
