"""Foxglove: `aspod log --mcap` read back with the `mcap` reader, and `aspod sim --foxglove` subscribed to live by a
WebSocket client speaking Foxglove's protocol (host_tools/sessions/foxglove.py)."""
from __future__ import annotations

import json
import math
import os
import struct
import sys
from collections import Counter
from pathlib import Path

import pytest

pytest.importorskip("foxglove", reason="the foxglove extra (foxglove-sdk) is not installed")
mcap_reader = pytest.importorskip("mcap.reader")

from protocol.schema import Direction
from timebase import RealClock
from host_tools.cli.main import main
from host_tools.exit_codes import EXIT_USAGE
from host_tools.sessions.decode import SessionDecoder
from tests.captures import read_capture, read_packets

DATA = Path(__file__).parent / "data"
MOVING = DATA / "replay_late_writes.pcapng"          # j2 jogs in it; events: state changes, a motion's end
TO_TOPIC = {"TelemetryJoints": ("/joints", "/arm", "/tf"), "TelemetryStatus": ("/status",),
            "TelemetryTracker": ("/tracker",)}
SCHEMAS = {"/joints": ("aspod.JointStates", "jsonschema", "json"), "/arm": ("foxglove.SceneUpdate", "protobuf",
                                                                           "protobuf"),
           "/tf": ("foxglove.FrameTransforms", "protobuf", "protobuf"), "/status": ("aspod.Status", "jsonschema", "json"),
           "/log": ("foxglove.Log", "protobuf", "protobuf")}


def expected(path: Path) -> tuple[Counter, dict[str, list[int]]]:
    """What the capture holds, read without the code under test: per topic, how many messages and at what times
    (the packet's nanoseconds plus its interface's if_tsoffset, as Wireshark shows it). The controller's telemetry
    on its topics, its events and the frames from it that do not decode on /log."""
    reader, packets = read_packets(path.read_bytes())
    _, frames, _ = read_capture(path)
    decoder = SessionDecoder()
    counts: Counter = Counter()
    times: dict[str, list[int]] = {}
    for packet, frame in zip(packets, frames):
        d = decoder.decode(frame.data, frame.time_s, frame.link, frame.direction)
        if frame.direction is not Direction.TO_HOST:
            continue
        topics = ("/log",) if d.message is None or d.class_name == "EVENT" else TO_TOPIC.get(d.name, ())
        started = reader.interfaces[packet.interface].tsoffset_s
        for topic in topics:
            counts[topic] += 1
            times.setdefault(topic, []).append(started * 10**9 + round(packet.time_s * 1e9))
    return counts, times


class JsonDecoders:
    """JSON messages (the jsonschema channels) as Python values, for `iter_decoded_messages`."""

    @staticmethod
    def decoder_for(message_encoding: str, schema):
        return json.loads if message_encoding == "json" else None


def read_mcap(path: Path) -> tuple[dict, list]:
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f)
        summary = reader.get_summary()
        messages = [(channel.topic, schema.name, message) for schema, channel, message in reader.iter_messages()]
    return summary, messages


def test_aspod_log_mcap_holds_foxgloves_topics_with_the_captures_counts_and_times(tmp_path, capsys):
    out = tmp_path / "session.mcap"
    assert main(["log", str(MOVING), "--mcap", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"# MCAP written to {out}:" in said and "on /joints" in said
    assert out.read_bytes()[:8] == b"\x89MCAP0\r\n"
    summary, messages = read_mcap(out)
    counts, times = expected(MOVING)
    assert counts["/joints"] > 10 and counts["/log"] >= 3
    assert Counter(topic for topic, _, _ in messages) == counts
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert (schema.name, schema.encoding, channel.message_encoding) == SCHEMAS[channel.topic], channel.topic
    for topic, want in times.items():
        assert [m.log_time for t, _, m in messages if t == topic] == want, topic
    # the joints in degrees as the console shows them and in radians as Foxglove's joint states have them
    joints = [json.loads(m.data) for t, _, m in messages if t == "/joints"]
    pairs = [(j["position"][k], j["position_deg"][k]) for j in joints for k in (0, 1, 2, 3, 5)]
    assert sum(deg != 0 for _, deg in pairs) > 10
    assert all(math.isclose(rad, math.radians(deg), rel_tol=1e-9) for rad, deg in pairs)
    assert all(math.isclose(j["position"][4], j["position_deg"][4] * 1e-3) for j in joints)     # the gripper: m, mm
    assert joints[0]["name"] == ["j1", "j2", "j3", "j4", "gripper", "mount"]
    assert joints[0]["timestamp"]["sec"] * 10**9 + joints[0]["timestamp"]["nsec"] == times["/joints"][0]


def test_the_arm_is_placed_by_its_forward_kinematics_and_the_events_are_foxglove_log_lines(tmp_path):
    """The MCAP's protobuf messages decoded with their own schemas (mcap-protobuf-support): the tip's frame on /tf
    and the scene's last point on /arm are where host_tools/apps/kinematics.py puts the tip for the joints on
    /joints; the events are foxglove.Log lines as aspod log shows them."""
    decoders = pytest.importorskip("mcap_protobuf.decoder")
    from host_tools.apps.kinematics import JointPose, forward
    out = tmp_path / "session.mcap"
    assert main(["log", str(MOVING), "--mcap", str(out)]) == 0
    with open(out, "rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[decoders.DecoderFactory(), JsonDecoders()])
        decoded = [(channel.topic, message.log_time, value) for _, channel, message, value
                   in reader.iter_decoded_messages()]
    joints = {t: value for topic, t, value in decoded if topic == "/joints"}
    tips = {t: value.transforms[-1] for topic, t, value in decoded if topic == "/tf"}
    scenes = {t: value.entities[0] for topic, t, value in decoded if topic == "/arm"}
    assert joints.keys() == tips.keys() == scenes.keys()
    moved = 0
    for t, j in joints.items():
        q = dict(zip(j["name"], j["position"]))
        want = forward(JointPose(q["j1"], q["j2"], q["j3"], q["mount"]))
        tip, scene = tips[t], scenes[t]
        assert tip.parent_frame_id == "world" and tip.child_frame_id == "tip"
        got = (tip.translation.x, tip.translation.y, tip.translation.z)
        assert all(math.isclose(a, b, abs_tol=1e-9) for a, b in zip(got, want)), (got, want)
        last = scene.lines[0].points[-1]
        assert all(math.isclose(a, b, abs_tol=1e-9) for a, b in zip((last.x, last.y, last.z), want))
        assert scene.frame_id == "world" and len(scene.spheres) == 5
        moved += j["position_deg"] != joints[min(joints)]["position_deg"]
    assert moved > 5
    logs = [value for topic, _, value in decoded if topic == "/log"]
    assert any(line.message.startswith("StateChanged(state=") and line.level == 2 for line in logs)   # Info


def test_aspod_log_mcap_refuses_what_it_may_not_write_or_without_its_extra(tmp_path, capsys, monkeypatch):
    text = tmp_path / "notes.mcap"
    text.write_text("my notes\n")
    assert main(["log", str(MOVING), "--mcap", str(text)]) == EXIT_USAGE
    assert "an existing file that is not an MCAP file; --force overwrites it" in capsys.readouterr().err
    assert text.read_text() == "my notes\n"
    assert main(["log", str(MOVING), "--mcap", str(tmp_path / "session.txt")]) == EXIT_USAGE
    assert "name it *.mcap" in capsys.readouterr().err
    assert main(["log", str(MOVING), "--mcap", str(MOVING)]) == EXIT_USAGE
    assert "that is the capture, an input of this run" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "foxglove", None)
    assert main(["log", str(MOVING), "--mcap", str(tmp_path / "s.mcap")]) == EXIT_USAGE
    assert ("log --mcap: needs the foxglove extra (foxglove is not installed): pip install 'aspod[foxglove]'"
            in capsys.readouterr().err)
    assert not (tmp_path / "s.mcap").exists()


@pytest.mark.pty
def test_aspod_sim_foxglove_serves_the_joints_live_to_a_websocket_client(tmp_path):
    """A real `aspod sim --pty --foxglove 0`, a host connected to it, and a WebSocket client speaking Foxglove's
    protocol (the SDK's subprotocol `foxglove.sdk.v1`): the server advertises the topics of `aspod log --mcap`, and
    a subscription to /joints brings the controller's joint telemetry as binary message data (opcode 1,
    subscription id, time, the JSON message). Waits are bounded on the simulator's own time (Child)."""
    sync_client = pytest.importorskip("websockets.sync.client")
    from host_tools.client.live import HostClient
    from host_tools.worlds.child import Child
    from protocol import auth
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}
    sim = Child(["sim", "--pty", "--foxglove", "0"], env=env)
    client = None
    try:
        ready = dict(sim.line().split(" ", 1) for _ in range(4))
        assert ready["ASPOD-FOXGLOVE"].startswith("ws://127.0.0.1:"), ready
        client = HostClient(ready["ASPOD-LINK"], auth.load_key(Path(ready["ASPOD-KEY"])))
        client.connect()
        with sync_client.connect(ready["ASPOD-FOXGLOVE"], subprotocols=["foxglove.sdk.v1"]) as ws:
            channels: dict[str, dict] = {}

            def advertised(seconds: float) -> bool:
                try:
                    said = json.loads(ws.recv(timeout=seconds))
                except TimeoutError:
                    return False
                if said["op"] == "advertise":
                    channels.update({c["topic"]: c for c in said["channels"]})
                return "/joints" in channels

            assert sim.wait_for(advertised, 30.0), channels
            assert {"/joints", "/arm", "/tf", "/tracker", "/status", "/log"} <= channels.keys()
            assert channels["/arm"]["schemaName"] == "foxglove.SceneUpdate"
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels["/joints"]["id"]}]}))
            got: list[bytes] = []

            def joints(seconds: float) -> bool:
                try:
                    data = ws.recv(timeout=seconds)
                except TimeoutError:
                    return False
                if isinstance(data, bytes) and data[0] == 1 and struct.unpack_from("<I", data, 1)[0] == 7:
                    got.append(data)
                return bool(got)

            assert sim.wait_for(joints, 30.0), "no /joints message"
        _, subscription, stamp = struct.unpack_from("<BIQ", got[0])
        message = json.loads(got[0][13:])
        assert message["name"] == ["j1", "j2", "j3", "j4", "gripper", "mount"] and len(message["position"]) == 6
        assert stamp == message["timestamp"]["sec"] * 10**9 + message["timestamp"]["nsec"]
        assert abs(stamp / 1e9 - RealClock.wall_time()) < 3600        # dated by the wall clock's day, not 1970
    finally:
        if client is not None:
            client.close()
        status, err = sim.stop()
    assert status == 0, err
