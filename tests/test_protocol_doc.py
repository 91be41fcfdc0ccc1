"""docs/protocol.md lists every enumeration a message field uses, each with all its values, and states the
link's rules with the numbers the code uses."""
from __future__ import annotations

import re
from pathlib import Path

from protocol import docgen
from protocol.link import LinkConfig
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.reliable import NOTHING_RECEIVED_ACK, REPLY_CACHE_SIZE
from protocol.states import Axis, ControllerState

DOC = (Path(__file__).resolve().parent.parent / "docs" / "protocol.md").read_text()


def section(title: str) -> str:
    """The text of the `## title` section, up to the next `## ` heading."""
    start = DOC.index(f"\n## {title}\n")
    end = DOC.find("\n## ", start + 1)
    return DOC[start:end if end >= 0 else None]


def test_every_enum_typed_field_of_every_message_has_its_enumeration_listed_with_every_value():
    used = {f.enum for spec in SCHEMA.by_id.values() for f in spec.fields if f.enum is not None}
    assert used == docgen.field_enums() and Axis in used
    tables = {Reason: section("Reason codes"), ControllerState: section("Controller states")}
    enumerations = section("Enumerations")
    for enum_type in used:
        if enum_type in tables:
            text = tables[enum_type]
        else:
            match = re.search(rf"\n### {enum_type.__name__}\n(.*?)(?=\n### |\Z)", enumerations, re.S)
            assert match, f"{enum_type.__name__} is not in the Enumerations section"
            text = match.group(1)
        for member in enum_type:
            assert re.search(rf"^\| {int(member)} \| `{member.name}` \|", text, re.M), (enum_type, member)
    assert "| 255 | `ALL` |" in enumerations


def test_the_document_states_the_rules_with_the_constants_of_the_code():
    rules = section("Refusals, sequence numbers and limits, exactly")
    flat = rules.replace("\n", " ")
    assert f"{NOTHING_RECEIVED_ACK} (`protocol/reliable.py` `NOTHING_RECEIVED_ACK`" in flat
    assert f"last {REPLY_CACHE_SIZE} sequence numbers" in flat
    assert f"window ({LinkConfig.window} in flight" in flat
    assert "`<axis>_speed_dps`" in flat and "0..360" in flat
    for nak in ("UNKNOWN_MESSAGE", "WRONG_DIRECTION", "SEQUENCE_GAP", "REPLAY"):
        assert f"`{nak}`" in flat
    assert "Only a reply uses up a sequence number" in flat


def test_a_handshake_frame_acknowledges_nothing_and_the_box_reads_without_power():
    """Two points of "What a client needs besides the tables", held by the controller: a HelloReply
    carries NOTHING_RECEIVED_ACK even after an earlier session's commands; GetBoxState reads the box
    while it is unpowered (no TelemetryTracker then)."""
    from protocol.framing import FrameReceiver
    from host_tools.worlds.world import LockstepBench
    to_host = bytearray()

    def tap(data: bytes) -> bytes:
        to_host.extend(data)
        return data
    bench = LockstepBench(seed=2, to_host=tap)
    try:
        assert "What a client needs besides the tables" in docgen.render()
        for _ in range(2):                          # a second session after the first one's commands
            assert bench.connect()
            for _ in range(3):
                assert bench.call(SCHEMA["Ping"].type(7)).ok
        box = bench.call(SCHEMA["GetBoxState"].type()).reply
        assert box.spec.name == "BoxState" and box.result == Reason.OK and box.main == 0
        assert not [t for t in bench.telemetry if t.spec.name == "TelemetryTracker"]
    finally:
        bench.close()
    frames = [f for f in FrameReceiver().feed(bytes(to_host)) if not isinstance(f, Exception)]
    replies = [f for f in frames if f.msg_id == SCHEMA["HelloReply"].id]
    assert len(replies) == 2 and {f.ack for f in replies} == {NOTHING_RECEIVED_ACK}
    session_frames = [f for f in frames if f.msg_id == SCHEMA["Pong"].id]
    assert max(f.ack for f in session_frames) < NOTHING_RECEIVED_ACK       # session frames do acknowledge
