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
    assert f"among the last {REPLY_CACHE_SIZE} it answered (`protocol/reliable.py` `REPLY_CACHE_SIZE`)" in flat
    assert f"the command window, {LinkConfig.window} (`LinkConfig.window`" in flat
    assert "`<axis>_speed_dps`" in flat and "0..360" in flat
    assert "Only a reply uses up a sequence number" in flat
    numbers = [int(n) for n in re.findall(r"\*\*Rule (\d+)\.", rules)]
    assert numbers == list(range(1, len(numbers) + 1)) and len(numbers) >= 10


def test_the_nak_table_lists_every_reason_the_link_sends():
    """Rule 10: every NAK reason the link sends (docs/vectors/refusals.json has one of each), and the fields a NAK
    refused for its header leaves empty."""
    rules = section("Refusals, sequence numbers and limits, exactly")
    table = {row.split("|")[1].strip(" `") for row in rules.splitlines() if row.startswith("| `")}
    sent = {"UNSUPPORTED_VERSION", "UNSUPPORTED_FLAGS", "BAD_LENGTH", "UNAUTHENTICATED", "BAD_MAC", "NO_SESSION",
            "UNKNOWN_MESSAGE", "WRONG_DIRECTION", "OUT_OF_RANGE", "SEQUENCE_GAP", "REPLAY", "SESSION_CLOSED"}
    assert table == sent and {r.name for r in Reason} >= sent
    flat = " ".join(rules.split())
    assert "`expected_seq`** is set only in `SEQUENCE_GAP`, `REPLAY` and `SESSION_CLOSED` NAKs" in flat
    assert f"at most {LinkConfig.nak_rate_per_s:g} of them a second (`LinkConfig.nak_rate_per_s`" in flat
    assert "names nothing: `refused_class`, `refused_seq`, `refused_msg` are 0" in flat
    assert "every NAK echoes" not in DOC


def test_the_line_timing_table_is_the_controllers_limit():
    from protocol.line import BAUD_RATES, max_telemetry_hz
    timing = section("Line timing")
    for baud in BAUD_RATES:
        assert re.search(rf"^\| {baud} \| .* \| {max_telemetry_hz(baud)} \|$", timing, re.M), baud


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
