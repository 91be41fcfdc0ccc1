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
