"""Session captures: pcapng written and read back, cut into frames as a receiver cuts them, decoded with and
without the key, counted, exported; broken captures reported with the offset where they break."""
from __future__ import annotations

import csv
import math
import struct
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from protocol import auth
from protocol.framing import MAX_ENCODED, decode_frame, encode_signed, find_frames
from protocol.messages import MESSAGES as M, SCHEMA
from protocol.schema import Direction, MsgClass
from protocol.states import AxisMode
from host_tools.cli.main import main
from host_tools.sessions.capture import CaptureWriter, SessionInfo
from host_tools.sessions.segments import SegmentCutter
from host_tools.sessions.decode import MAC_BAD, MAC_OK, MAC_UNCHECKED, SessionDecoder
from host_tools.sessions.pcapng import INBOUND, OUTBOUND, PcapngWriter
from host_tools.sessions.stats import SessionStats
from host_tools.worlds.world import LockstepBench
from tests.captures import read_capture, read_frames, read_packets

PSK = b"capture-test-key-0123456789abcdef"
H2C, C2H = Direction.TO_CONTROLLER, Direction.TO_HOST


def record_session(path: Path, seconds: float = 1.0, to_controller=lambda b: b) -> LockstepBench:
    """A real lock-step session (handshake, telemetry at 20 Hz, pings) captured as it crossed the line."""
    bench = LockstepBench(PSK, seed=4)
    writer = CaptureWriter.create(path, SessionInfo(clock="simulated", tool="test", seed=4, settings={"x": 1}))

    def tap(direction, then=lambda b: b):
        def hook(data: bytes) -> bytes:
            writer.write("link", direction, data, bench.clock.now())
            return then(data)
        return hook

    bench.to_controller = tap(H2C, to_controller)
    bench.to_host = tap(C2H)
    assert bench.connect()
    assert bench.call(M["SetTelemetryRate"](20)).ok
    for token in range(5):
        assert bench.call(M["Ping"](token)).reply.token == token
    bench.run_for(seconds)
    writer.close()
    bench.close()
    return bench


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, LockstepBench]:
    path = tmp_path_factory.mktemp("capture") / "session.pcapng"
    return path, record_session(path)


def test_pcapng_round_trip_keeps_times_to_the_nanosecond_directions_comments_and_interfaces(tmp_path):
    path = tmp_path / "t.pcapng"
    out = open(path, "wb")
    writer = PcapngWriter(out, comment="section", application="me")
    radio, optical = writer.add_interface("radio"), writer.add_interface("optical", "the photonic link")
    writer.write_packet(radio, 12.000000001, b"\x01\x02\x03", OUTBOUND, comment="hello")
    writer.write_packet(optical, 1_700_000_000.25, b"\x05" * 9, INBOUND, original_length=20)
    out.close()
    reader, (first, second) = read_packets(path.read_bytes())
    assert reader.error is None and reader.comment == "section" and reader.application == "me"
    assert [(i.name, i.description, i.tsresol_exp) for i in reader.interfaces] == [
        ("radio", "", 9), ("optical", "the photonic link", 9)]
    assert (first.interface, first.data, first.direction, first.comment) == (0, b"\x01\x02\x03", OUTBOUND, "hello")
    assert round(first.time_s * 1e9) == 12_000_000_001
    assert (second.interface, second.data, second.original_length, second.direction) == (1, b"\x05" * 9, 20, INBOUND)
    assert second.time_s == 1_700_000_000.25


def _big_endian_file() -> bytes:
    """A pcapng section written big-endian by hand (as a big-endian capturing machine would)."""
    def block(kind, body):
        body += b"\x00" * (-len(body) % 4)
        return struct.pack(">II", kind, len(body) + 12) + body + struct.pack(">I", len(body) + 12)
    shb = block(0x0A0D0D0A, struct.pack(">IHHq", 0x1A2B3C4D, 1, 0, -1))
    idb = block(1, struct.pack(">HHI", 147, 0, 0) + struct.pack(">HH", 2, 4) + b"wire" + struct.pack(">HH", 0, 0))
    epb = block(6, struct.pack(">IIIII", 0, 0, 3_000_000, 2, 2) + b"\xab\xcd\x00\x00"
                + struct.pack(">HHI", 2, 4, 2) + struct.pack(">HH", 0, 0))
    return shb + idb + epb


def test_a_big_endian_file_reads_the_same(tmp_path):
    path = tmp_path / "be.pcapng"
    path.write_bytes(_big_endian_file())
    reader, (packet,) = read_packets(path.read_bytes())
    assert reader.error is None
    assert reader.interfaces[0].name == "wire"
    assert (packet.data, packet.time_s, packet.direction) == (b"\xab\xcd", 3.0, OUTBOUND)


def test_a_real_session_decodes_every_frame_and_verifies_every_mac_with_the_key(session):
    path, bench = session
    capture, frames, _ = read_capture(path)
    assert capture.error is None and capture.warnings == []
    assert capture.info.clock == "simulated" and capture.info.seed == 4 and capture.info.settings == {"x": 1}
    decoder = SessionDecoder(PSK)
    decoded = [decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length) for f in frames]
    assert decoded and all(d.error == "" and d.mac == MAC_OK for d in decoded)
    names = [d.name for d in decoded]
    assert names[:4] == ["Hello", "HelloCookie", "Hello", "HelloReply"]
    pongs = [d.message.token for d in decoded if d.name == "Pong"]
    assert pongs == [0, 1, 2, 3, 4]
    telemetry = [d for d in decoded if d.frame.cls == MsgClass.TELEMETRY]
    # what the host received is what the capture holds: the same telemetry, in the same order
    assert [d.message for d in telemetry] == bench.telemetry
    assert all(d.direction is C2H for d in telemetry)
    assert all(d.direction is H2C for d in decoded if d.name in ("Hello", "Ping", "SetTelemetryRate"))


def test_without_the_key_macs_are_unchecked_and_with_another_key_every_signed_frame_fails(session):
    path, _ = session
    frames = read_frames(path)
    plain = [SessionDecoder(None).decode(f.data, f.time_s, f.link, f.direction) for f in frames]
    assert {d.mac for d in plain} == {MAC_UNCHECKED}
    decoder = SessionDecoder(b"another-key-0123456789abcdef0123")
    wrong = [decoder.decode(f.data, f.time_s, f.link, f.direction) for f in frames]
    assert {d.mac for d in wrong} == {MAC_BAD}
    assert all(d.message is not None for d in wrong)       # the fields still read; only trust is withheld


def test_a_hosts_no_session_nak_verifies_under_the_handshake_key_and_under_no_other():
    """A host with no session NAKs a frame it cannot verify under its handshake key (protocol.md, rule 10)."""
    nak = SCHEMA["Nak"]
    payload = nak.encode(nak.type(8, MsgClass.EVENT, 3, SCHEMA["StateChanged"].id, 0, bytes(8)))
    hs = auth.handshake_keys(PSK, is_controller=False)
    decoder = SessionDecoder(PSK)
    for key, direction, verdict in ((hs.tx, H2C, MAC_OK), (hs.rx, H2C, MAC_BAD), (hs.tx, C2H, MAC_BAD)):
        wire, _ = encode_signed(MsgClass.LINK, 0, 0xFFFF, nak.id, payload, key, 1)
        decoded = decoder.decode(wire[1:-1], 0.0, "link", direction)
        assert decoded.mac == verdict and decoded.message.spec.name == "Nak", (direction, verdict)


def test_stats_count_round_trips_and_retransmissions_and_telemetry_gaps(tmp_path):
    dropped = []

    def lose_the_first_ping_2(data: bytes) -> bytes:    # the line loses the first write carrying Ping(2)
        frames = [decode_frame(segment) for segment in find_frames(data)[0]]
        if not dropped and any(f.msg_id == SCHEMA["Ping"].id and f.payload == (2).to_bytes(4, "little")
                               for f in frames):
            dropped.append(data)
            return b""
        return data

    path = tmp_path / "lossy.pcapng"
    record_session(path, to_controller=lose_the_first_ping_2)
    decoder, stats = SessionDecoder(PSK), SessionStats()
    for f in read_frames(path):
        stats.add(decoder.decode(f.data, f.time_s, f.link, f.direction))
    assert dropped and stats.sessions == 1
    assert stats.retransmissions[(H2C, "COMMAND")] >= 1        # the lost one was sent again
    assert stats.rtt_s["COMMAND"].n == 6 - 1                   # Karn: the retransmitted request is not timed
    assert 0 < stats.rtt_s["COMMAND"].least <= stats.rtt_s["COMMAND"].most < 1.0
    assert stats.unanswered == 0 and stats.telemetry_lost == 0 and not stats.errors
    report = stats.report()
    assert "round trip COMMAND: n=5" in report and "seen again" in report


def test_the_tap_cuts_the_same_frames_however_the_bytes_are_chunked():
    frames = [encode_signed(1, n, 0, *SCHEMA.encode(M["Ping"](n)), b"k" * 32, n + 1)[0] for n in range(5)]
    stream = b"".join(frames) + b"\x07\x07"           # and a partial frame at the end
    whole = SegmentCutter().feed(stream)
    tap = SegmentCutter()
    bytewise = [seg for i in range(len(stream)) for seg in tap.feed(stream[i:i + 1])]
    assert whole == bytewise and len(whole) == 5


def test_the_tap_holds_at_most_one_frame_and_reports_an_overlong_run_with_its_length():
    tap = SegmentCutter()
    out = []
    for _ in range(100):
        out += tap.feed(b"\x41" * 1000)
        assert len(tap._pending) <= MAX_ENCODED
    out += tap.feed(b"\x00")
    ((data, length),) = out
    assert len(data) == MAX_ENCODED and length == 100_000


def test_a_truncated_capture_keeps_every_frame_before_the_break_and_names_its_offset(session, tmp_path):
    path, _ = session
    data = path.read_bytes()
    whole = read_frames(path)
    starts = [f.offset for f in whole]
    cut = tmp_path / "cut.pcapng"
    for size in sorted({starts[3] + 1, starts[10] + 7, starts[-1] + 5, len(data) - 1}):
        cut.write_bytes(data[:size])
        capture, frames, _ = read_capture(cut)
        complete = sum(1 for s in starts if s < size and s + _block_len(data, s) <= size)
        assert len(frames) == complete
        assert capture.error is not None and "truncated" in capture.error.reason
        assert capture.error.offset == max(s for s in starts if s < size)
        assert [f.data for f in frames] == [f.data for f in whole[:complete]]


def _block_len(data: bytes, offset: int) -> int:
    return struct.unpack_from("<I", data, offset + 4)[0]


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_corrupt_bytes_anywhere_are_reported_never_raised(session, data):
    path, _ = session
    original = bytearray(path.read_bytes())
    spots = data.draw(st.lists(st.integers(0, len(original) - 1), min_size=1, max_size=4))
    for spot in spots:
        original[spot] = data.draw(st.integers(0, 255))
    reader, packets = read_packets(bytes(original))      # never raises: a break is kept in `error`
    assert reader.error is None or reader.error.offset < len(original)
    decoder = SessionDecoder(PSK)
    for p in packets:
        decoder.decode(p.data, p.time_s, "link", C2H, p.original_length)


def test_not_a_capture_at_all(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("these are my notes, not a capture\n")
    capture, frames, _ = read_capture(path)
    assert frames == [] and capture.error.offset == 0
    assert "section header" in capture.error.reason


def test_a_capture_from_another_schema_says_so_by_its_hash(tmp_path):
    path = tmp_path / "old.pcapng"
    writer = CaptureWriter.create(path, SessionInfo(clock="wall", tool="old", schema_hash=0x1234))
    writer.write("link", H2C, encode_signed(1, 0, 0, *SCHEMA.encode(M["Ping"](1)), b"k" * 32, 1)[0], 5.0)
    writer.close()
    capture, frames, _ = read_capture(path)
    assert len(frames) == 1
    assert any("0000000000001234" in w and f"{SCHEMA.hash:016x}" in w for w in capture.warnings)


# ---- the command ---------------------------------------------------------------------------------------------

def test_aspod_log_prints_filters_counts_and_exports(session, tmp_path, capsys):
    path, _ = session
    key = tmp_path / "k.key"
    auth.write_key(key, PSK)
    assert main(["log", str(path), "--key-file", str(key), "--class", "command"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if not line.startswith("#")]
    assert lines and all(" COMMAND " in line and line.endswith("mac=ok") for line in lines)
    assert sum("Ping(token=" in line for line in lines) == 5

    assert main(["log", str(path), "--message", "telemetryjoints", "--csv", str(tmp_path / "j.csv")]) == 0
    table = (tmp_path / "j.csv").read_text().splitlines()
    assert table[0].startswith("time_s,link,direction,class,seq,message,uptime_ms [ms],homed,j1_pos [deg],"
                               "j1_vel [deg/s],j1_current [A],j1_mode,")
    assert len(table) > 10 and all(",TelemetryJoints," in row for row in table[1:])
    rows = list(csv.DictReader(table))
    assert {row["j1_mode"] for row in rows} <= {mode.name for mode in AxisMode}        # names, not numbers
    assert main(["log", str(path), "--si"]) == 2                  # only with a table
    assert "--si: only with --csv" in capsys.readouterr().err

    assert main(["log", str(path), "--stats"]) == 0
    assert "round trip COMMAND: n=6" in capsys.readouterr().out

    png = tmp_path / "s.png"
    assert main(["log", str(path), "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_aspod_log_csv_in_the_consoles_degrees_or_with_si_in_radians(tmp_path):
    """The table's angles are the console's degrees, each column's unit in its header; `--si` gives radians."""
    moving = Path(__file__).parent / "data" / "replay_late_writes.pcapng"       # j2 jogs in it
    tables = {}
    for name, extra in (("deg", ()), ("si", ("--si",))):
        out = tmp_path / f"{name}.csv"
        assert main(["log", str(moving), "--message", "TelemetryJoints", "--csv", str(out), *extra]) == 0
        tables[name] = list(csv.DictReader(out.read_text().splitlines()))
    angles = [name for name in tables["deg"][0] if name.endswith(" [deg]") or name.endswith(" [deg/s]")]
    pairs = [(float(a[n]), float(b[n.replace("[deg", "[rad")])) for a, b in zip(tables["deg"], tables["si"])
             for n in angles]
    assert len(tables["si"]) == len(tables["deg"]) > 10 and sum(deg != 0 for deg, _ in pairs) > 10
    assert all(math.isclose(rad, math.radians(deg), rel_tol=1e-5, abs_tol=1e-9) for deg, rad in pairs)


def test_aspod_log_on_a_broken_capture_decodes_what_it_can_and_fails_with_the_offset(session, tmp_path, capsys):
    path, _ = session
    cut = tmp_path / "cut.pcapng"
    cut.write_bytes(path.read_bytes()[:-30])
    assert main(["log", str(cut)]) == 1
    captured = capsys.readouterr()
    assert "Hello(" in captured.out
    assert "breaks at byte" in captured.err and "truncated" in captured.err


def test_aspod_log_refuses_bad_filters_by_name(session, capsys):
    path, _ = session
    assert main(["log", str(path), "--class", "gossip"]) == 2
    assert "--class gossip: not a message class" in capsys.readouterr().err
    assert main(["log", str(path), "--message", "Teleport"]) == 2
    assert main(["log", str(path), "--plot", "/no/such/folder/x.png"]) == 2
    assert main(["log", "/no/such/capture.pcapng"]) == 2
    assert "/no/such/capture.pcapng" in capsys.readouterr().err


@pytest.mark.parametrize("clock", ["simulated", "paced", "wall"])
def test_a_worlds_capture_is_dated_by_its_start_and_keeps_its_own_times(tmp_path, clock):
    """Wireshark showed a world's captures in 1970: their times count from the world's start. Each interface's
    if_tsoffset now holds the wall-clock second the capture began (a wall-clock capture is Unix time already)."""
    path = tmp_path / "c.pcapng"
    writer = CaptureWriter.create(path, SessionInfo(clock=clock, tool="test"), started_s=1_800_000_000.7)
    writer.write("link", Direction.TO_CONTROLLER, b"\x00\x01\x02\x00", 2.5)
    writer.close()
    reader, packets = read_packets(path.read_bytes())
    assert [i.tsoffset_s for i in reader.interfaces] == [0 if clock == "wall" else 1_800_000_000]
    assert [p.time_s for p in packets] == [2.5]


def test_the_plot_has_a_panel_for_what_the_session_carried_and_marks_its_faults(tmp_path):
    """It drew four panels whatever the session had ("not in this session" on the empty ones) and no events."""
    from host_tools.sessions.export import SessionPlot
    lost = Path(__file__).parent / "data" / "replay_lag_given_up.pcapng"        # telemetry, a LINK_LOST fault
    plot = SessionPlot()
    decoder = SessionDecoder(None)
    for f in read_frames(lost):
        plot.add(decoder.decode(f.data, f.time_s, f.link, f.direction))
    assert plot.panels() == ["position", "current", "link"]                      # no tracker in it: no panel
    assert len(plot.faults) == 1 and plot.faults[0][1] == "LINK_TIMEOUT" and plot.events.points()[0]
    png = tmp_path / "lost.png"
    assert main(["log", str(lost), "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert SessionPlot().panels() == ["link"]


def test_the_capture_format_is_as_sessions_md_says(tmp_path):
    """docs/sessions.md, "The capture format", read with struct alone: the blocks and their options, the link type,
    the direction bits, the time base (if_tsresol 9, if_tsoffset) and the section comment's grammar."""
    import json
    import re
    path = tmp_path / "doc.pcapng"
    writer = CaptureWriter.create(path, SessionInfo(clock="paced", tool="aspod sim", seed=3), started_s=1_800_000_000.7)
    frame = encode_signed(MsgClass.LINK, 0, 0, SCHEMA["Ack"].id, b"", bytes(32), 1)[0]
    writer.write("link", H2C, frame, 1.5)
    writer.write("link", C2H, frame + frame, 2.25)
    writer.close()
    data, blocks, at = path.read_bytes(), [], 0
    while at < len(data):
        kind, total = struct.unpack_from("<II", data, at)
        assert struct.unpack_from("<I", data, at + total - 4)[0] == total and total % 4 == 0
        blocks.append((kind, data[at + 8:at + total - 4]))
        at += total

    def options(body: bytes, at: int) -> dict:
        found = {}
        while True:
            code, size = struct.unpack_from("<HH", body, at)
            if code == 0:
                return found
            found[code] = body[at + 4:at + 4 + size]
            at += 4 + size + (-size % 4)
    assert [k for k, _ in blocks] == [0x0A0D0D0A, 1, 6, 6, 6]
    shb = blocks[0][1]
    assert struct.unpack_from("<IHHq", shb) == (0x1A2B3C4D, 1, 0, -1)
    shb_options = options(shb, 16)
    assert shb_options[4] == b"aspod sim"
    comment = shb_options[1].decode()
    match = re.fullmatch(r"aspod-session (\{.*\})", comment)
    doc = json.loads(match.group(1))
    assert set(doc) == {"format", "protocol_version", "schema_hash", "clock", "tool", "seed", "settings"}
    assert doc["format"] == 1 and doc["clock"] == "paced" and re.fullmatch(r"[0-9a-f]{16}", doc["schema_hash"])
    assert list(doc) == sorted(doc) and "\n" not in comment
    idb = blocks[1][1]
    assert struct.unpack_from("<HHI", idb) == (147, 0, 0)
    idb_options = options(idb, 8)
    assert idb_options[2] == b"link" and idb_options[9] == bytes([9])
    assert struct.unpack("<q", idb_options[14])[0] == 1_800_000_000
    packets = []
    for _, body in blocks[2:]:
        iface, high, low, captured, original = struct.unpack_from("<IIIII", body)
        flags = struct.unpack("<I", options(body, 20 + captured + (-captured % 4))[2])[0]
        packets.append((iface, ((high << 32) | low) / 1e9, body[20:20 + captured], original, flags))
    assert [(p[1], p[4]) for p in packets] == [(1.5, 2), (2.25, 1), (2.25, 1)]    # 2 outbound, 1 inbound
    assert all(p[2] == frame[1:-1] and p[3] == len(frame) - 2 and b"\x00" not in p[2] for p in packets)
