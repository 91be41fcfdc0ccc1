"""Bad session captures given to `aspod log` and `aspod replay`: refused with the reason, never a traceback or hang."""
from __future__ import annotations

import json
import os
import struct

import pytest

from protocol.messages import PROTOCOL_VERSION, SCHEMA
from host_tools.apps.replay import ReplayError, check_world_event
from host_tools.cli.main import main
from host_tools.sessions.capture import MARK, MAX_SETTING_CHARS, MAX_SETTING_ENTRIES, WORLD, SessionInfo, WorldEvent
from host_tools.sessions.pcapng import (IF_TSRESOL, LINKTYPE_USER1, MAX_TSRESOL_EXP, NANOSECONDS, OUTBOUND,
                                        PcapngWriter)
from host_tools.worlds.settings import PlantSettings
from tests.captures import read_capture, read_packets


@pytest.mark.parametrize("command", ["log", "replay"])
def test_a_fifo_is_refused_not_waited_on(tmp_path, capsys, command):
    fifo = tmp_path / "capture.pcapng"
    os.mkfifo(fifo)
    assert main([command, str(fifo)]) == 2
    assert "FIFO" in capsys.readouterr().err


@pytest.mark.parametrize("command, status", [("log", 1), ("replay", 2)])
def test_a_large_file_is_read_as_a_stream_and_what_is_not_a_capture_is_said_at_its_first_block(tmp_path, capsys,
                                                                                            command, status):
    big = tmp_path / "big.pcapng"
    with open(big, "wb") as f:
        f.truncate(4 << 30)          # 4 GiB, sparse: nothing is written, nothing but the first block is read
    assert main([command, str(big)]) == status
    assert "at byte 0: not a pcapng file" in capsys.readouterr().err


GOOD = {"format": 1, "protocol_version": PROTOCOL_VERSION, "schema_hash": f"{SCHEMA.hash:016x}",
        "clock": "simulated", "tool": "aspod bench", "seed": 2,
        "settings": {"plant": PlantSettings().to_dict(), "params": {"j1_kp": 2.0}}}


def _comment(**changes) -> str:
    return MARK + json.dumps({**GOOD, **changes})


def _capture_file(path, comment: str) -> str:
    with open(path, "wb") as f:
        writer = PcapngWriter(f, comment=comment)
        writer.write_packet(writer.add_interface("link"), 0.5, b"\x01\x02", OUTBOUND)
    return str(path)


def test_a_good_session_description_reads():
    assert SessionInfo.from_comment(_comment()).seed == 2


def test_settings_at_their_bounds_read():
    settings = {"params": {f"p{i:04}": 1.0 for i in range(MAX_SETTING_ENTRIES)}, "impairment": "x" * MAX_SETTING_CHARS,
                "k" * MAX_SETTING_CHARS: ["y" * MAX_SETTING_CHARS] * MAX_SETTING_ENTRIES}
    assert SessionInfo.from_comment(_comment(settings=settings, tool="t" * MAX_SETTING_CHARS)).settings == settings


@pytest.mark.parametrize("comment, reason", [
    (MARK + "[]", "not a JSON object"), (MARK + "null", "not a JSON object"), (MARK + "5", "not a JSON object"),
    (MARK + '"x"', "not a JSON object"), (MARK + "[" * 60_000, "nests deeper"),
    (MARK + '{"a": ' + "{" * 5000 + "}" * 5000 + "}", "nests deeper"),
    (MARK + json.dumps(GOOD).replace('"protocol_version": 1', '"protocol_version": 1e400'), "out of range"),
    (_comment(protocol_version=1.9), "protocol_version"), (_comment(protocol_version="1"), "protocol_version"),
    (_comment(seed=[1, 2]), "seed"), (_comment(seed={}), "seed"), (_comment(seed=2**100), "seed"),
    (_comment(seed=3.7), "seed"), (_comment(seed=-1), "seed"), (_comment(seed=True), "seed"),
    (_comment(clock=["simulated"]), "clock"), (_comment(schema_hash=5), "schema_hash"),
    (_comment(settings=[1]), "settings"), (_comment(tool=7), "tool"),
    (_comment(settings={"params": {f"p{i}": 1.0 for i in range(MAX_SETTING_ENTRIES + 1)}}),
     rf"settings\['params'\] holds {MAX_SETTING_ENTRIES + 1} entries; at most {MAX_SETTING_ENTRIES}"),
    (_comment(settings={"faults": [["jam:j2", 1.0]] * 5000}), r"settings\['faults'\] holds 5000 entries"),
    (_comment(settings={"impairment": "radio," * 1000}),
     rf"settings\['impairment'\] is a string of 6000 characters; at most {MAX_SETTING_CHARS}"),
    (_comment(settings={"params": {"k" * 2000: 1.0}}), r"a key in settings\['params'\] is a string of 2000"),
    (_comment(settings={"a": {"b": ["x" * 1025]}}), r"settings\['a'\]\['b'\]\[0\] is a string of 1025"),
    (_comment(tool="t" * 5000), "tool is a string of 5000 characters"),
])
def test_a_bad_session_description_is_refused_with_the_field_named(comment, reason):
    with pytest.raises(ValueError, match=reason):
        SessionInfo.from_comment(comment)


@pytest.mark.parametrize("plant, reason", [
    ({"start": "0001-01-01T00:00:00+00:00"}, "outside the controller clock's range"),
    ({"start": "9999-01-01T00:00:00+00:00"}, "outside the controller clock's range"),
    ({"start": "2026-01-01T00:00:00"}, "UTC offset"), ({"tracker": "no"}, "tracker"),
    ({"gravity": ["earth"]}, "gravity"), ({"clouds": 5}, "clouds"), ({"payload_kg": 10**400}, "payload_kg"),
    ({"payload_kg": float("nan")}, "payload_kg"),
])
def test_bad_plant_settings_are_refused_as_the_command_line_would(plant, reason):
    with pytest.raises(ValueError, match=reason):
        PlantSettings.from_dict({**PlantSettings().to_dict(), **plant})


@pytest.mark.parametrize("changes, reason", [
    ({"seed": [1, 2]}, "seed"), ({"seed": 2**100}, "seed"), ({"protocol_version": 1.9}, "protocol_version"),
    ({"settings": {"plant": {**PlantSettings().to_dict(), "tracker": "no"}, "params": {}}}, "tracker"),
    ({"settings": {"plant": PlantSettings().to_dict(), "params": {"j1_kp": 10**400}}}, "j1_kp"),
    ({"settings": {"plant": {**PlantSettings().to_dict(), "start": "0001-01-01T00:00:00+00:00"}, "params": {}}},
     "range"),
    ({"settings": {"plant": PlantSettings().to_dict(), "params": {f"p{i}": 1 for i in range(5000)}}},
     "settings['params'] holds 5000 entries; at most"),
])
def test_replay_refuses_a_bad_session_description_naming_the_field(tmp_path, capsys, changes, reason):
    path = _capture_file(tmp_path / "c.pcapng", _comment(**changes))
    assert main(["replay", path]) == 2
    assert reason in capsys.readouterr().err


def test_log_on_a_bad_session_description_warns_and_decodes(tmp_path, capsys):
    path = _capture_file(tmp_path / "c.pcapng", MARK + "[]")
    assert main(["log", path]) == 0
    assert "not a JSON object" in capsys.readouterr().err


def _world_capture(path, *events: bytes, times: tuple[float, ...] = ()) -> str:
    """A capture of one frame at 0.5 s and `events` on the world interface, at `times` (default: each at 0.3 s)."""
    with open(path, "wb") as f:
        writer = PcapngWriter(f, comment=_comment())
        writer.write_packet(writer.add_interface("link"), 0.5, b"\x01\x02", OUTBOUND)
        world = writer.add_interface(WORLD, "", LINKTYPE_USER1)
        for event, time_s in zip(events, times or (0.3,) * len(events)):
            writer.write_packet(world, time_s, event)
    return str(path)


@pytest.mark.parametrize("event, reason", [
    ({"action": "inject", "args": 5}, "args must be a list"), ({"action": "inject", "args": None}, "args must be"),
    ({"action": "set_payload", "args": [10**400]}, "payload kg"),
    ({"action": "set_payload", "args": [1e308]}, "0..1000"),
    ({"action": "inject", "args": ["jam:j9"]}, "j9"), ({"control": {"op": "payload", "kg": 1e308}}, "0..1000"),
    ({"control": {"op": "pause"}}, "pause"), ({"control": None}, "JSON object"), ({"args": ["x"]}, "action"),
])
def test_replay_refuses_a_world_event_the_control_endpoint_would_refuse(tmp_path, capsys, event, reason):
    path = _world_capture(tmp_path / "w.pcapng", json.dumps({"action": "inject", "args": ["supply_sag"]}).encode(),
                          json.dumps(event).encode())
    assert main(["replay", path]) == 2
    err = capsys.readouterr().err
    assert "world event 1 " in err and reason in err


@pytest.mark.parametrize("data", [b"[" * 60_000, b'{"a":' * 60_000, b"[1, 2]", b"\xff{}", b'{"action": NaN}'])
def test_replay_refuses_a_world_event_that_does_not_parse_rather_than_leave_it_out(tmp_path, capsys, data):
    assert main(["replay", _world_capture(tmp_path / "w.pcapng", data)]) == 2
    assert "world event 0 (at byte" in capsys.readouterr().err


def test_log_shows_odd_world_events_without_a_traceback(tmp_path, capsys):
    path = _world_capture(tmp_path / "w.pcapng", *(json.dumps(e).encode() for e in (
        {"action": "inject", "args": 5}, {"action": "inject", "args": None}, {"action": [1]},
        {"control": {"op": "payload", "kg": 2}})), b"[" * 60_000)
    assert main(["log", path]) == 0
    out = capsys.readouterr().out
    assert "inject(5)" in out and "inject(None)" in out and "control {'op': 'payload'" in out


@pytest.mark.parametrize("time_s", [1e5, 1e9])
def test_replay_refuses_a_recording_longer_than_a_day_before_simulating(tmp_path, capsys, time_s):
    with open(tmp_path / "t.pcapng", "wb") as f:
        writer = PcapngWriter(f, comment=_comment())
        writer.write_packet(writer.add_interface("link"), time_s, b"\x01\x02", OUTBOUND)
    assert main(["replay", str(tmp_path / "t.pcapng")]) == 2
    assert "86400 s" in capsys.readouterr().err


@pytest.mark.parametrize("command, option", [("log", "--csv"), ("replay", "--output")])
def test_an_output_that_is_the_capture_itself_or_a_folder_is_refused_and_the_capture_kept(tmp_path, capsys, command,
                                                                                      option):
    capture = _capture_file(tmp_path / "c.pcapng", _comment())
    kept = (tmp_path / "c.pcapng").read_bytes()
    os.link(capture, tmp_path / "hard.pcapng")
    for output, said in ((capture, "an input of this run"), (tmp_path / "hard.pcapng", "an input of this run"),
                         (tmp_path, "a folder, not a file")):
        assert main([command, capture, option, str(output)]) == 2, output
        assert said in capsys.readouterr().err
    assert (tmp_path / "c.pcapng").read_bytes() == kept



# ---- timestamps: an interface's resolution, world events' times ---------------------------------------------

def _with_tsresol(path, exponent: int) -> tuple[bytes, int]:
    """A capture whose link interface says its timestamps are in 10^-exponent s, and where that interface's
    block starts (right after the section header)."""
    data = open(_capture_file(path, _comment()), "rb").read()
    nanoseconds = bytes([IF_TSRESOL, 0, 1, 0, NANOSECONDS])          # as PcapngWriter declares every interface
    assert data.count(nanoseconds) == 1
    return data.replace(nanoseconds, bytes([IF_TSRESOL, 0, 1, 0, exponent])), struct.unpack_from("<I", data, 4)[0]


@pytest.mark.parametrize("exponent", [0x7f, MAX_TSRESOL_EXP + 1, 64])
def test_an_interface_whose_timestamps_are_finer_than_picoseconds_is_refused_where_it_is_declared(
        tmp_path, capsys, exponent):
    data, at = _with_tsresol(tmp_path / "c.pcapng", exponent)
    reader, packets = read_packets(data)
    assert reader.error is not None and reader.error.offset == at
    assert f"if_tsresol 10^-{exponent} s" in reader.error.reason and not packets
    (tmp_path / "c.pcapng").write_bytes(data)
    assert main(["replay", str(tmp_path / "c.pcapng")]) == 2
    assert f"breaks at byte {at}: if_tsresol 10^-{exponent} s" in capsys.readouterr().err


@pytest.mark.parametrize("exponent", [0, 6, 9, MAX_TSRESOL_EXP])
def test_an_interface_at_any_resolution_a_writer_uses_is_read(tmp_path, exponent):
    data, _ = _with_tsresol(tmp_path / "c.pcapng", exponent)
    reader, packets = read_packets(data)
    assert reader.error is None
    assert packets[0].time_s == pytest.approx(0.5e9 / 10 ** exponent)      # 0.5 s written as nanoseconds


def test_an_interface_resolution_that_is_not_one_byte_is_refused(tmp_path):
    data = open(_capture_file(tmp_path / "c.pcapng", _comment()), "rb").read()
    one_byte = bytes([IF_TSRESOL, 0, 1, 0, NANOSECONDS, 0, 0, 0])      # code, length, the byte, padding
    data = data.replace(one_byte, bytes([IF_TSRESOL, 0, 2, 0, NANOSECONDS, 6, 0, 0]))
    assert "if_tsresol of 2 bytes; the option is one byte" in read_packets(data)[0].error.reason


@pytest.mark.parametrize("time_s", [-1.0, float("nan"), float("-inf")])
def test_a_world_event_before_the_session_started_is_refused_with_its_index_and_offset(tmp_path, time_s):
    _, _, (event,) = read_capture(_world_capture(tmp_path / "w.pcapng", b'{"action": "inject", "args": ["supply_sag"]}'))
    with pytest.raises(ReplayError, match=rf"world event 0 \(at byte {event.offset}\) is at {time_s:.6g} s: before "
                                          r"the session started"):
        check_world_event(WorldEvent(time_s, event.event, event.offset, event.index))
