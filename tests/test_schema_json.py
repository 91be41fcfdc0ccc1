"""`aspod schema --json` and docs/schema.json (issue 37): the declaration as data, read from the one declaration the
codec uses; the committed file current; the schema hash recomputed from that file alone, by the recipe
docs/protocol.md gives, with nothing of protocol/ importable."""
from __future__ import annotations

import hmac
import importlib
import json
import random
import re
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

from host_tools import strict_json
from host_tools.cli.main import main
from protocol import auth, declaration, framing
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.schema import Direction, MsgClass
from protocol.reasons import Reason
from protocol.states import FAULT_DOCS, SWITCH_POSITIONS, Fault, Switch, TrackerWarning

ROOT = Path(__file__).resolve().parent.parent
COMMITTED = ROOT / "docs" / "schema.json"


@pytest.fixture(scope="module")
def data() -> dict:
    return strict_json.loads(COMMITTED.read_text(encoding="utf-8"))


def test_the_committed_file_is_what_the_command_prints(capsys):
    assert main(["schema", "--json"]) == 0
    printed = capsys.readouterr().out
    assert printed == COMMITTED.read_text(encoding="utf-8"), "docs/schema.json is stale: run `make docs`"
    assert printed == declaration.render() and printed.startswith(declaration.HEAD)
    assert json.loads(printed) == json.loads(json.dumps(declaration.declaration()))


def test_every_message_and_field_is_the_declared_one_with_its_offsets(data):
    assert (data["format"], data["format_version"]) == (declaration.FORMAT, declaration.FORMAT_VERSION)
    assert data["protocol_version"] == PROTOCOL_VERSION and data["schema_hash"] == f"{SCHEMA.hash:016x}"
    by_id = {m["id"]: m for m in data["messages"]}
    assert len(by_id) == len(data["messages"]) and set(by_id) == set(SCHEMA.by_id)
    assert [m["id"] for m in data["messages"]] == sorted(by_id)
    for msg_id, m in by_id.items():
        spec = SCHEMA.by_id[msg_id]
        assert SCHEMA.by_name[m["name"]] is spec
        assert (MsgClass[m["class"]], Direction[m["direction"]], m["reply"], m["teleop"], m["doc"]) == \
            (spec.cls, spec.direction, spec.reply, spec.teleop, spec.doc)
        assert m["reply"] is None or m["reply"] in SCHEMA.by_name
        assert {MsgClass[c] for c in m["sent_in"]} == {c for c in MsgClass if SCHEMA.class_allowed(spec, c)}
        assert m["payload_size"] == spec.size <= data["framing"]["max_payload"]
        assert [f["name"] for f in m["fields"]] == [f.name for f in spec.fields]
        offset = 0
        for f, fld in zip(m["fields"], spec.fields):
            assert f["offset"] == offset, (m["name"], f["name"])
            assert f["size"] == struct.calcsize("<" + fld.struct_code)
            assert (f["type"], f["unit"] or "", f["default"], f["doc"]) == (fld.type, fld.unit, fld.default, fld.doc)
            assert (f["min"], f["max"]) == (fld.range if fld.range else (None, None))
            assert f["enum"] == (fld.enum.__name__ if fld.enum else None)
            assert f["enum"] is None or f["enum"] in data["enums"]
            fixed = data["types"]["fixed"].get(f["type"])
            assert fixed is None or fixed["size"] == f["size"]
            offset += f["size"]
        assert offset == m["payload_size"], m["name"]


def test_a_payload_laid_out_by_the_file_decodes_as_the_codec_decodes_it(data):
    """Pack a message field by field at the file's offsets, with struct codes named by the file's types."""
    codes = {"u8": "B", "u16": "H", "u32": "I", "u64": "Q", "i8": "b", "i16": "h", "i32": "i", "f32": "f",
             "bool": "B"}
    m = next(m for m in data["messages"] if m["name"] == "MotionAccepted")
    payload = bytearray(m["payload_size"])
    values = {"result": 28, "axis": 1, "motion_id": 7, "limit": "j2_max_deg", "limit_value": 90.0, "asked": 95.5}
    for f in m["fields"]:
        value = values.get(f["name"], 0)
        if f["type"].startswith(("str", "text")):
            payload[f["offset"]:f["offset"] + f["size"]] = value.encode().ljust(f["size"], b"\0")
        else:
            struct.pack_into("<" + codes[f["type"]], payload, f["offset"], value)
    decoded = SCHEMA["MotionAccepted"].decode(bytes(payload))
    assert {k: getattr(decoded, k) for k in values} == values


def test_the_enumerations_are_the_declared_ones(data):
    enums = data["enums"]
    python = {f.enum.__name__: f.enum for s in SCHEMA.by_id.values() for f in s.fields if f.enum is not None}
    python |= {"Fault": Fault, "TrackerWarning": TrackerWarning, "MsgClass": MsgClass}
    assert set(enums) == set(python)
    for name, e in enums.items():
        members = [m for key, m in python[name].__members__.items() if key == m.name]
        assert [(m["name"], m["value"]) for m in e["members"]] == [(m.name, int(m)) for m in members], name
    faults = {m["name"]: m for m in enums["Fault"]["members"]}
    assert enums["Fault"]["flags"] and not enums["Reason"]["flags"]
    assert (faults["LINK_LOST"]["doc"], faults["LINK_LOST"]["remedy"]) == FAULT_DOCS[Fault.LINK_LOST]
    reasons = {m["name"]: m for m in enums["Reason"]["members"]}
    assert (reasons["SOFT_LIMIT"]["value"], reasons["SOFT_LIMIT"]["remedy"]) == (28, Reason.SOFT_LIMIT.remedy)
    switches = {m["name"]: m["positions"] for m in enums["Switch"]["members"]}
    assert switches == {s.name: [p.name for p in SWITCH_POSITIONS[s]] for s in Switch}
    assert {m["name"] for m in enums["Axis"]["members"]} >= {"J1", "MOUNT", "ALL"}


def test_the_constants_name_where_they_come_from(data):
    names = set()
    for c in data["constants"]:
        module = importlib.import_module(c["source"].removesuffix(".py").replace("/", "."))
        value = module
        for part in c["name"].split("."):
            value = getattr(value, part)
        assert value == c["value"], c["name"]
        names.add(c["name"])
    assert {"REPLY_CACHE_SIZE", "SEQ_MOD", "MAX_UNDELIVERED_EVENTS", "LinkConfig.window",
            "LinkConfig.link_timeout_s", "MAX_PAYLOAD"} <= names


def _crc(data_bytes: bytes, crc: dict) -> int:
    """A bitwise CRC from the catalogue's parameters (Williams's model), as a client would write one."""
    width, poly, reg = crc["width"], crc["poly"], crc["init"]
    top, mask = 1 << (width - 1), (1 << width) - 1
    for byte in data_bytes:
        if crc["refin"]:
            byte = int(f"{byte:08b}"[::-1], 2)
        reg ^= byte << (width - 8)
        for _ in range(8):
            reg = ((reg << 1) ^ poly) & mask if reg & top else (reg << 1) & mask
    if crc["refout"]:
        reg = int(f"{reg:0{width}b}"[::-1], 2)
    return reg ^ crc["xorout"]


def test_a_signed_frame_is_read_by_the_file_framing_crc_and_keys(data):
    """A client written from the file alone: it derives the session key, finds the header, counter, payload, tag
    and CRC where the layouts say, and checks them as the framing does."""
    fr, au = data["framing"], data["authentication"]
    assert _crc(b"123456789", fr["crc"]) == fr["crc"]["check"] == zlib.crc32(b"123456789")
    sample = random.Random(3).randbytes(300)
    assert _crc(sample, fr["crc"]) == zlib.crc32(sample)
    psk, host_nonce, controller_nonce = bytes(range(32)), b"h" * 16, b"c" * 16
    keys = {k["name"]: k for k in au["keys"]}
    session = keys["session_h2c"]
    derived = hmac.digest(psk, session["label"].encode() + host_nonce + controller_nonce, "sha256")
    assert derived == auth.session_keys(psk, host_nonce, controller_nonce, is_controller=False).tx.key
    assert hmac.digest(psk, keys["handshake_c2h"]["label"].encode(), "sha256") == \
        auth.handshake_keys(psk, is_controller=True).tx.key
    assert hmac.digest(psk, keys["nak_c2h"]["label"].encode() + b"ctrl-id1", "sha256") == \
        auth.nak_key(psk, b"ctrl-id1").key
    assert hmac.digest(psk, keys["session_c2h"]["label"].encode() + host_nonce + controller_nonce, "sha256") == \
        auth.session_keys(psk, host_nonce, controller_nonce, is_controller=True).tx.key
    assert hmac.digest(psk, keys["handshake_h2c"]["label"].encode(), "sha256") == \
        auth.handshake_keys(psk, is_controller=False).tx.key

    payload = SCHEMA["Ping"].encode(SCHEMA["Ping"].type(0xA5A5))
    wire = framing.encode_frame(int(MsgClass.COMMAND), 3, 9, SCHEMA["Ping"].id, payload, key=derived, counter=77)
    assert wire[0] == wire[-1] == fr["delimiter"]
    from cobs import cobs
    raw = cobs.decode(wire[1:-1])
    header = {h["name"]: int.from_bytes(raw[h["offset"]:h["offset"] + h["size"]], "little") for h in fr["header"]}
    assert header == {"version": fr["version"], "flags": fr["flags"][0]["value"], "class": 1, "seq": 3, "ack": 9,
                      "msg_id": SCHEMA["Ping"].id, "length": len(payload)}
    parts = {p["name"]: p for p in fr["layouts"]["authenticated"]}

    def part(name: str) -> bytes:
        p = parts[name]
        size = header["length"] if p["size"] == "length" else p["size"]
        start = p["offset"] if "offset" in p else len(raw) + p["from_end"]
        return raw[start:start + size]
    assert int.from_bytes(part("counter"), "little") == 77 and part("payload") == payload
    tag_at = len(raw) + parts["tag"]["from_end"]
    assert part("tag") == hmac.digest(derived, raw[:tag_at], "sha256")[:au["tag_size"]]
    assert int.from_bytes(part("crc"), "little") == _crc(raw[:-fr["crc"]["size"]], fr["crc"])


def _recipe_from_the_doc() -> str:
    doc = (ROOT / "docs" / "protocol.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", doc, re.S)
    recipe = [b for b in blocks if "schema.json" in b]
    assert len(recipe) == 1
    assert recipe[0] == declaration.HASH_RECIPE_PYTHON
    return recipe[0]


def _run_recipe(folder: Path) -> list[str]:
    """The doc's recipe in a Python that can import nothing of this checkout (-I: no PYTHONPATH, no current folder,
    no user site) in a folder holding only docs/schema.json."""
    code = "import sys\n" + _recipe_from_the_doc() + "assert not {'protocol', 'host_tools'} & set(sys.modules)\n"
    done = subprocess.run([sys.executable, "-I", "-c", code], cwd=folder, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


def test_replies_are_sent_in_only_the_classes_of_the_requests_they_answer(data):
    sent_in = {m["name"]: m["sent_in"] for m in data["messages"]}
    assert sent_in["Pong"] == sent_in["Closed"] == sent_in["Status"] == ["COMMAND"]
    assert sent_in["Result"] == ["COMMAND", "URGENT"]            # EStop's and Stop's reply, and any refusal
    for m in data["messages"]:
        if m["reply"] is not None:
            assert m["class"] in sent_in[m["reply"]], m["name"]
    to_host = SCHEMA.receivable(Direction.TO_HOST)           # and the host refuses one in another (WRONG_DIRECTION)
    pong = SCHEMA["Pong"].id
    assert (pong, int(MsgClass.URGENT)) not in to_host and (pong, int(MsgClass.COMMAND)) in to_host


def test_the_nak_table_is_data_and_the_doc_renders_the_same_rows(data):
    """Rule 10 declared once (protocol/link_rules.py): the file holds every row, docs/protocol.md shows each."""
    from protocol import link_rules
    rules = data["link"]["naks"]["rules"]
    assert rules == [r.as_data() for r in link_rules.NAK_RULES]
    doc = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")
    for rule in rules:
        assert Reason[rule["reason"]] is Reason(rule["code"])
        assert rule["signed_with"] in data["link"]["naks"]["signing"]
        assert set(rule["names"]) <= {f["name"] for f in next(m for m in data["messages"] if m["name"] == "Nak")[
            "fields"]}
        assert f"| `{rule['reason']}` | {rule['stage']} | {rule['when']} |" in doc
        assert rule["stage"] in [stage["stage"] for stage in data["link"]["naks"]["check_order"]]
    key_names = {k["name"] for k in data["authentication"]["keys"]}
    for ends in data["link"]["naks"]["signing_keys"].values():
        assert {name for end in ends.values() for name in end.values()} <= key_names
    assert set(data["link"]["naks"]["signing_keys"]) == set(data["link"]["naks"]["signing"])
    by_reason = {r["reason"]: r for r in rules}
    assert by_reason["UNSUPPORTED_VERSION"]["names"] == [] and by_reason["NO_SESSION"]["signed_with"] == "no_session"
    assert [c["class"] for c in data["link"]["classes"]] == [c.name for c in MsgClass]
    header = data["link"]["handshake_header"]
    assert (header["class"], header["seq"], header["ack"]) == ("LINK", 0, 65535)


def test_a_frame_that_fails_two_checks_is_refused_at_the_first_in_the_declared_order():
    """The check order (link.naks.check_order) as the controller's link makes it: a frame wrong at two stages is
    answered for the earlier one, for each pair of neighbouring stages that answer with a Nak."""
    from host_tools.sessions import vectors
    line = vectors._Line()
    line.connect()
    ping = SCHEMA["Ping"]
    token, gap = ping.encode(ping.type(1)), line.controller._commands.expected + 3
    other_key = bytes(32)
    cases = [   # (the reason of the earlier stage, a frame wrong at it and at the next)
        ("UNSUPPORTED_VERSION", vectors._made(line, MsgClass.COMMAND, gap, ping.id, token, version=2, key=other_key)),
        ("BAD_MAC", vectors._made(line, MsgClass.COMMAND, gap, 0x0777, token, key=other_key)),
        ("UNKNOWN_MESSAGE", vectors._made(line, MsgClass.COMMAND, gap, 0x0777, token)),
        ("SEQUENCE_GAP", vectors._made(line, MsgClass.COMMAND, gap, ping.id, token[:-1])),
    ]
    for reason, wire in cases:
        answer = framing.decode_frame(line.send_to_controller(wire)[1:-1])
        nak = SCHEMA.decode(answer.msg_id, answer.payload)
        assert nak.spec.name == "Nak" and Reason(nak.reason).name == reason, (reason, nak)
        line.controller._commands._nak_sent_for = None           # a gap is NAKed once per expected number


def test_a_hello_is_checked_in_the_declared_order(data):
    """link.hello_checks as the controller's link makes them: a Hello with another version and schema hash gets a
    HelloCookie first (the cookie before anything it carries), and its echo the version's refusal (the version
    before the hash)."""
    from protocol.controller_link import ControllerLink
    names = [c["check"] for c in data["link"]["hello_checks"]]
    assert names.index("cookie") < names.index("version") < names.index("schema_hash")
    psk = bytes(range(32))
    link = ControllerLink(psk, lambda msg, urgent, now: None)
    keys = auth.handshake_keys(psk, is_controller=False)
    hello = SCHEMA["Hello"]

    def answer(cookie: bytes, counter: int, now: float):
        body = hello.encode(hello.type(PROTOCOL_VERSION + 1, SCHEMA.hash ^ 1, bytes(16), cookie))
        link.feed(framing.encode_frame(MsgClass.LINK, 0, 0xFFFF, hello.id, body, keys.tx, counter), now)
        link.poll(now + 1.0)
        frame = framing.decode_frame(link.take_frame(now + 1.0)[1:-1])
        return SCHEMA.decode(frame.msg_id, frame.payload)
    first = answer(bytes(auth.COOKIE_BYTES), 1, 0.0)
    assert first.spec.name == "HelloCookie"
    second = answer(first.cookie, 2, 1.0)
    assert second.spec.name == "HelloReply" and Reason(second.result) is Reason.UNSUPPORTED_VERSION


def test_the_line_table_and_the_cookie_label_are_the_codes(data):
    from protocol import line
    assert [(b["baud"], b["max_telemetry_hz"]) for b in data["line"]["bauds"]] == \
        [(b, line.max_telemetry_hz(b)) for b in line.BAUD_RATES]
    cookie = data["authentication"]["cookie"]
    assert cookie["label"].encode() == auth.COOKIE_LABEL and cookie["size"] == auth.COOKIE_BYTES
    secret, nonce, slot = bytes(range(16)), bytes(range(16, 32)), 123
    made = hmac.digest(secret, cookie["label"].encode() + nonce + struct.pack("<q", slot), "sha256")[:cookie["size"]]
    assert made == auth.hello_cookie(secret, nonce, slot)


def test_the_schema_hash_is_recomputed_from_the_file_alone(tmp_path):
    (tmp_path / "docs").mkdir()
    shutil.copy(COMMITTED, tmp_path / "docs" / "schema.json")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["docs", "schema.json"]
    computed, stated = _run_recipe(tmp_path)
    assert computed == stated == f"{SCHEMA.hash:016x}"
    # the recipe reads the declaration, not the stated hash: a field's range changed changes it
    changed = json.loads(COMMITTED.read_text())
    field = next(f for m in changed["messages"] if m["name"] == "SetTelemetryRate" for f in m["fields"])
    field["hash_range"] = "(0, 201)"
    (tmp_path / "docs" / "schema.json").write_text(json.dumps(changed))
    computed, stated = _run_recipe(tmp_path)
    assert stated == f"{SCHEMA.hash:016x}" and computed != stated


def test_the_recipe_prose_is_in_the_doc_and_the_file(data):
    doc = " ".join((ROOT / "docs" / "protocol.md").read_text().split())
    assert " ".join(declaration.HASH_RECIPE.split()) in doc
    assert data["schema_hash_recipe"] == declaration.HASH_RECIPE


def test_output_writes_the_file_and_replaces_only_a_declaration(tmp_path, capsys):
    out = tmp_path / "schema.json"
    assert main(["schema", "--json", "--output", str(out)]) == 0
    assert out.read_text() == COMMITTED.read_text() and "wrote" in capsys.readouterr().out
    assert main(["schema", "--json", "-o", str(out)]) == 0            # its own kind: replaced
    notes = tmp_path / "notes.txt"
    notes.write_text("the only copy of my notes\n")
    assert main(["schema", "--json", "--output", str(notes)]) == 2
    err = capsys.readouterr().err
    assert "not a declaration of aspod schema's" in err and "--force" in err
    assert notes.read_text() == "the only copy of my notes\n"
    other = tmp_path / "other.json"
    other.write_text('{"format": "aspod-trajectory"}\n')
    assert main(["schema", "--json", "--output", str(other)]) == 2
    assert other.read_text() == '{"format": "aspod-trajectory"}\n'
    assert main(["schema", "--json", "--output", str(other), "--force"]) == 0
    assert other.read_text() == COMMITTED.read_text()
    log = tmp_path / "run.log"
    assert main(["schema", "--json", "--log-file", str(log), "--output", str(log)]) == 2
    assert "writes there too" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "other.json", "run.log", "schema.json"]


@pytest.mark.parametrize("argv, said", [
    (["schema", "--output", "x.json"], "--output writes the JSON declaration: say --json too"),
    (["schema", "--json", "--output", "."], "a folder, not a file"),
    (["schema", "--json", "--output", "no/such/folder/x.json"], "no folder"),
])
def test_bad_arguments_exit_2_with_the_reason(tmp_path, monkeypatch, capsys, argv, said):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert said in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_option_is_refused_with_the_command_usage(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["schema", "--xml"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "usage: aspod schema" in err and "unrecognized arguments: --xml" in err


def test_without_json_a_summary(capsys):
    assert main(["schema"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"protocol v{PROTOCOL_VERSION}, schema hash {SCHEMA.hash:016x}: {len(SCHEMA.by_id)} messages")
    assert "aspod schema --json" in out
