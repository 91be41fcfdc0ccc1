"""The generated Lua dissector, run by the real tshark over a real session's capture, reads what `aspod log` reads.

Skipped, saying so, where tshark is not installed (`.ci/run` installs it where apt-get can).
"""
from __future__ import annotations

import math
import os
import shutil
import struct

import pytest

from protocol import framing
from protocol.framing import HEADER
from protocol.messages import SCHEMA
from protocol.schema import Direction, MsgClass
from host_tools.cli.main import main
from timebase import RealClock
from host_tools.sessions.decode import SessionDecoder
from host_tools.sessions.pcapng import OUTBOUND, PcapngWriter
from host_tools.sessions.wireshark import generate_dissector
from tests.aspod_cli import ASPOD
from tests.captures import read_frames, read_packets
from host_tools.worlds.child import run
from tests.test_session_capture import PSK, record_session

TSHARK = shutil.which("tshark")
needs_tshark = pytest.mark.skipif(TSHARK is None, reason="tshark is not installed (apt-get install tshark); "
                                                         "the dissector was not run")
FIELDS = ["frame.number", "aspod.message", "aspod.class", "aspod.seq", "aspod.ack", "aspod.crc_good",
          "aspod.counter", "aspod.pong.token", "aspod.telemetryjoints.j2_pos", "aspod.telemetryjoints.j2_mode",
          "aspod.hello.schema_hash", "_ws.expert.message"]


def tshark_fields(lua, capture) -> list[dict[str, str]]:
    cmd = [TSHARK, "-n", "-X", f"lua_script:{lua}", "-r", str(capture), "-T", "fields", "-E", "occurrence=f"]
    for name in FIELDS:
        cmd += ["-e", name]
    done = run(cmd, text=True, timeout_s=120)
    assert done.returncode == 0, done.stderr
    assert "Lua" not in done.stderr and "error" not in done.stderr.lower(), done.stderr
    return [dict(zip(FIELDS, line.split("\t"))) for line in done.stdout.splitlines()]


@pytest.fixture(scope="module")
def capture_and_dissector(tmp_path_factory):
    folder = tmp_path_factory.mktemp("wireshark")
    capture = folder / "session.pcapng"
    record_session(capture, seconds=0.5)
    lua = folder / "aspod.lua"
    assert main(["wireshark", "-o", str(lua)]) == 0
    return capture, lua


def test_the_dissector_is_generated_from_the_declaration():
    text = generate_dissector()
    assert f"{SCHEMA.hash:016x}" in text
    for spec in SCHEMA.by_id.values():
        for field in spec.fields:
            assert f'"aspod.{spec.name.lower()}.{field.name}"' in text


@needs_tshark
def test_tshark_with_the_dissector_decodes_every_frame_as_aspod_log_does(capture_and_dissector):
    capture_path, lua = capture_and_dissector
    rows = tshark_fields(lua, capture_path)
    decoder = SessionDecoder(PSK)
    ours = [decoder.decode(f.data, f.time_s, f.link, f.direction) for f in read_frames(capture_path)]
    assert len(rows) == len(ours) > 20
    for row, d in zip(rows, ours):
        assert row["aspod.message"] == d.name
        assert row["aspod.class"] == str(d.frame.cls)
        assert (int(row["aspod.seq"]), int(row["aspod.ack"])) == (d.frame.seq, d.frame.ack)
        assert row["aspod.crc_good"] in ("1", "True")
        assert int(row["aspod.counter"]) == d.frame.counter
        if d.name == "Pong":
            assert int(row["aspod.pong.token"]) == d.message.token
        if d.name == "TelemetryJoints":
            assert math.isclose(float(row["aspod.telemetryjoints.j2_pos"]), d.message.j2_pos, rel_tol=1e-6,
                                abs_tol=1e-6)
            assert int(row["aspod.telemetryjoints.j2_mode"]) == d.message.j2_mode
        if d.name == "Hello":
            assert int(row["aspod.hello.schema_hash"]) == SCHEMA.hash
    assert {d.frame.cls for d in ours} >= {MsgClass.LINK, MsgClass.COMMAND, MsgClass.TELEMETRY}


@needs_tshark
def test_tshark_marks_a_corrupted_frame_and_goes_on(capture_and_dissector, tmp_path):
    capture_path, lua = capture_and_dissector
    frames = read_frames(capture_path)
    data = bytearray(capture_path.read_bytes())
    victim = frames[5]
    data[victim.offset + 28 + 3] ^= 0x40      # a byte inside the sixth frame's wire bytes (past the EPB header)
    broken = tmp_path / "broken.pcapng"
    broken.write_bytes(bytes(data))
    rows = tshark_fields(lua, broken)
    assert len(rows) == len(frames)
    assert rows[5]["_ws.expert.message"] != "" or rows[5]["aspod.crc_good"] in ("0", "False")
    assert all(r["aspod.crc_good"] in ("1", "True") for i, r in enumerate(rows) if i != 5)


@needs_tshark
def test_tshark_marks_what_aspod_log_refuses_in_frames_whose_crc_is_good(capture_and_dissector, tmp_path):
    """A frame with a good CRC is not yet a message: a version or must-understand flag this protocol does not
    speak, a field value the codec refuses (an enum out of its values, a NaN, a declared range, a str16 of
    bytes that are no name and no terminator), or a packet cut short in the capture. The dissector said nothing
    about any of these (each showed as a good message); now each has an expert note, as `aspod log` an error."""
    _, lua = capture_and_dissector
    ping_id, ping = SCHEMA.encode(SCHEMA["Ping"].type(7))
    header = HEADER.pack

    def frame(body: bytes) -> bytes:
        return framing.seal(body)[1:-1]

    def message(name: str, payload: bytes, version: int = 1, flags: int = 0) -> bytes:
        spec = SCHEMA[name]
        return frame(header(version, flags, int(spec.cls), 1, 1, spec.id, len(payload)) + payload)

    good = message("Ping", ping)
    cases = [
        ("good", good, None),
        ("version 2", message("Ping", ping, version=2), None),
        ("flags 0x40", message("Ping", ping, flags=0x40), None),
        ("enum out of range", message("Pong", bytes([200]) + bytes(8)), None),
        ("NaN", message("ParamSet", b"x" + bytes(15) + struct.pack("<f", math.nan)), None),
        ("str16 not a name, no terminator", message("ParamGet", b"\xff\xfe\xc3\x28" * 4), None),
        ("outside the declared range", message("SetClock", bytes(6)), None),
        ("cut short in the capture", good, len(good) + 100),
    ]
    path = tmp_path / "refused.pcapng"
    with open(path, "wb") as out:
        pcap = PcapngWriter(out)
        link = pcap.add_interface("link")
        for i, (_, data, original) in enumerate(cases):
            pcap.write_packet(link, i * 0.01, data, OUTBOUND, original_length=original)
    rows = tshark_fields(lua, path)
    decoder = SessionDecoder(None)
    assert len(rows) == len(cases)
    for (what, data, original), row in zip(cases, rows):
        refused = decoder.decode(data, 0.0, "link", Direction.TO_CONTROLLER, original).error
        assert bool(refused) == (what != "good"), what
        assert (row["_ws.expert.message"] != "") == bool(refused), (what, refused, row)
    assert rows[0]["aspod.message"] == "Ping"


@needs_tshark
def test_wireshark_shows_the_sessions_date_and_who_spoke(capture_and_dissector):
    """Captures were dated 1970 (the session's own times from 0), and Source and Destination were empty."""
    capture_path, lua = capture_and_dissector
    frames = read_frames(capture_path)
    started = read_packets(capture_path.read_bytes())[0].interfaces[0].tsoffset_s
    assert abs(started - RealClock.wall_time()) < 24 * 3600          # today's: written when the fixture recorded it
    cmd = [TSHARK, "-n", "-X", f"lua_script:{lua}", "-r", str(capture_path), "-T", "fields",
           "-e", "frame.time_epoch", "-e", "_ws.col.Source", "-e", "_ws.col.Destination"]
    done = run(cmd, text=True, timeout_s=120)
    rows = [line.split("\t") for line in done.stdout.splitlines()]
    assert len(rows) == len(frames) > 20
    for (epoch, source, destination), frame in zip(rows, frames):
        assert math.isclose(float(epoch), started + frame.time_s, abs_tol=1e-6)
        assert (source, destination) == (("host", "controller") if frame.direction is Direction.TO_CONTROLLER
                                         else ("controller", "host"))


@needs_tshark
def test_install_puts_the_dissector_where_tshark_loads_it_by_itself(capture_and_dissector, tmp_path):
    capture_path, _ = capture_and_dissector
    env = {**os.environ, "HOME": str(tmp_path / "home"), "XDG_CONFIG_HOME": str(tmp_path / "home" / ".config")}
    done = run([*ASPOD, "wireshark", "--install"], text=True, env=env, timeout_s=120)
    assert done.returncode == 0, done.stderr
    installed = tmp_path / "home" / ".local" / "lib" / "wireshark" / "plugins" / "aspod.lua"
    assert installed.read_text() == generate_dissector() and str(installed) in done.stdout
    plain = run([TSHARK, "-n", "-r", str(capture_path), "-T", "fields", "-e", "aspod.message"], text=True, env=env,
                timeout_s=120)                       # no -X lua_script: the plugin folder's
    assert plain.returncode == 0 and plain.stdout.splitlines()[:2] == ["Hello", "HelloCookie"], plain.stdout
    again = run([*ASPOD, "wireshark", "--install"], text=True, env=env, timeout_s=120)
    assert again.returncode == 0                     # its own file, replaced by the same
    installed.write_text("-- my own plugin\n")
    refused = run([*ASPOD, "wireshark", "--install"], text=True, env=env, timeout_s=120)
    assert refused.returncode == 2 and installed.read_text() == "-- my own plugin\n"   # not ours: kept
