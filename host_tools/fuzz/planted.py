"""Known defects, planted on purpose, that prove `aspod fuzz` finds bugs.

The emulator never loads this module. A test, the benchmark, or a person checking the fuzzer does:

- `planted_codec_target()`: the codec target over a copy of `MessageSpec.decode` whose length check is off by
  one (a payload one byte longer than its message is accepted, and the extra byte is silently dropped). No
  exception comes of it; only the codec target's round-trip oracle can see it.
- `python -m host_tools.fuzz.planted sim ...`: `aspod sim` whose `BoxDial` handler looks the dial up in a
  table one entry short, so a dial at exactly its declared maximum (100 %) raises IndexError in the
  controller. Every other value, and every other message, behaves as in the real controller. A fuzzer finds
  it only if it reaches the handler (a session, a valid MAC, counter and sequence number) with a float at
  its declared boundary.
- `planted_controller_link_target()`: the `controller-link` target in process, over that same BoxDial handler:
  the engine must reach it as the black-box fuzzer does, through a session, a valid MAC and sequence number.
- `planted_hang_target()`: a walker over length-prefixed records that does not step over a record of length 0,
  so it loops for ever on such an input: a hang, which `aspod fuzz` must end, save and replay as one.
"""
from __future__ import annotations

from protocol.errors import ParseError
from protocol.reasons import Reason

PLANTED_DIAL_PCT = 100.0          # the one BoxDial value that trips the planted handler


def planted_decode(spec, payload: bytes):
    """`MessageSpec.decode` with an off-by-one length check (the planted defect)."""
    size = spec.size
    if not size <= len(payload) <= size + 1:          # the defect: should be len(payload) == size
        raise ParseError(Reason.BAD_LENGTH, f"{spec.name} takes {size} payload bytes, got {len(payload)}")
    return spec.decode(payload[:size])


def planted_codec_target():
    """The codec target, decoding through `planted_decode` (`aspod fuzz host_tools.fuzz.planted:planted_codec_target`)."""
    from host_tools.fuzz.targets import CodecTarget
    return CodecTarget(decode=planted_decode)


def planted_walk(data: bytes) -> int:
    """The number of length-prefixed records in `data` (a length byte, then that many bytes each); the planted
    defect: a record of length 0 is never stepped over."""
    at = records = 0
    while at < len(data):
        length = data[at]
        if length == 0:
            continue                                         # the defect: should step over it (at += 1)
        at += 1 + length
        records += 1
    return records


def planted_hang_target():
    """A target feeding `planted_walk` (`aspod fuzz host_tools.fuzz.planted:planted_hang_target`)."""
    from host_tools.fuzz.targets import Target

    class WalkTarget(Target):
        name = "planted-walk"
        about = "length-prefixed records, with a planted hang on a record of length 0"

        def one_input(self, data: bytes) -> None:
            planted_walk(data)
    return WalkTarget()


def planted_controller_link_target():
    """The controller-link target, its controller's BoxDial handler the planted one
    (`aspod fuzz host_tools.fuzz.planted:planted_controller_link_target`)."""
    from host_tools.fuzz.link_targets import ControllerLinkTarget
    plant_dial_defect()
    return ControllerLinkTarget()


def plant_dial_defect() -> None:
    """Replace the tracker's BoxDial handler by the planted one (in this process only, for every controller built
    after: firmware_py/handlers.py)."""
    from firmware_py.tracker.commands import TrackerCommands
    real = TrackerCommands._box_dial
    if getattr(real, "planted", False):
        return                                               # planted already (a target made again)
    table = [round(p * 1023 / 100) for p in range(100)]     # the defect: 0..99 %, one entry short of 100 %

    def planted_box_dial(self, msg, now):
        table[int(msg.percent)]                              # IndexError at exactly 100 %
        return real(self, msg, now)
    planted_box_dial.planted = True
    TrackerCommands._box_dial = planted_box_dial


if __name__ == "__main__":
    # `aspod ...` run as a program in this process, after planting (runpy: the command line is above this layer)
    import runpy
    plant_dial_defect()
    runpy.run_module("host_tools.cli.main", run_name="__main__", alter_sys=True)
