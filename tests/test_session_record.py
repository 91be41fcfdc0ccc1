"""Recording where users already are: `aspod sim --record --can-log` and `aspod teleop --record`, as real
subprocesses over a real pty; the captures decoded by `aspod log`, the CAN log by cantools with the DBC."""
from __future__ import annotations

from pathlib import Path

import can
import cantools
import pytest

from protocol import auth
from host_tools.sessions.decode import MAC_OK, SessionDecoder
from host_tools.worlds.child import run
from host_tools.worlds.settings import PlantSettings
from tests import test_e2e
from tests.captures import read_capture

pytestmark = pytest.mark.pty
ASPOD = test_e2e.ASPOD
env, sim_factory = test_e2e.env, test_e2e.sim_factory      # the fixtures, shared
DBC = Path(__file__).resolve().parent.parent / "protocol" / "hal.dbc"


def decoded(path: Path, psk: bytes):
    capture, frames, _ = read_capture(path)
    assert capture.error is None, capture.error
    decoder = SessionDecoder(psk)
    return capture, [decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length) for f in frames]


def test_sim_and_teleop_record_the_same_session_and_the_hal_bus_goes_to_a_python_can_log(sim_factory, tmp_path):
    sim_capture, host_capture, can_log = tmp_path / "sim.pcapng", tmp_path / "teleop.pcapng", tmp_path / "hal.asc"
    key = tmp_path / "link.key"           # a key of the user's own, to check the captures' MACs once the sim is gone
    auth.write_key(key, bytes(range(32)))
    sim = sim_factory("--pty", "--record", str(sim_capture), "--can-log", str(can_log), "--seed", "5",
                      "--no-tracker", "--key-file", str(key))
    done = sim.teleop("ping 7\nstatus\nping 8\nquit\n", "--record", str(host_capture))
    assert done.returncode == 0, done.stderr.decode()
    status, _ = sim.stop()
    assert status == 0
    psk = auth.load_key(sim.key_path)

    host_info, host_frames = decoded(host_capture, psk)
    sim_info, sim_frames = decoded(sim_capture, psk)
    assert host_info.info.tool == "aspod teleop" and host_info.info.clock == "wall"
    assert sim_info.info.tool == "aspod sim" and sim_info.info.clock == "paced" and sim_info.info.seed == 5
    assert PlantSettings.from_dict(sim_info.info.settings["plant"]).tracker is False
    assert sim_info.info.settings["params"]["telemetry_hz"] >= 0
    for frames in (host_frames, sim_frames):
        assert all(d.error == "" and d.mac == MAC_OK for d in frames)
        pongs = [d.message.token for d in frames if d.name == "Pong"]      # a busy machine may make the host send
        assert list(dict.fromkeys(pongs)) == [7, 8], pongs                  # a Ping again: answered again, the same
    # every frame the host sent reached the controller's capture, and the other way round, in order
    for direction in {d.direction for d in host_frames}:
        host_side = [d.frame.signed for d in host_frames if d.direction is direction]
        sim_side = [d.frame.signed for d in sim_frames if d.direction is direction]
        shorter = min(len(host_side), len(sim_side))
        assert shorter >= 3 and host_side[:shorter] == sim_side[:shorter]
    # the times: Unix time for the host, the world's seconds for the sim
    assert host_frames[0].time_s > 1e9 and 0 <= sim_frames[0].time_s < 600

    out = run(ASPOD + ["log", str(sim_capture), "--key-file", str(sim.key_path), "--message", "pong"], text=True,
              timeout_s=60)
    assert out.returncode == 0, out.stderr
    assert "Pong(result=OK, token=7" in out.stdout and "mac=ok" in out.stdout

    db = cantools.database.load_file(DBC)
    names = set()
    with can.LogReader(str(can_log)) as reader:
        for n, msg in enumerate(reader):
            names.add(db.get_message_by_frame_id(msg.arbitration_id).name)
            db.decode_message(msg.arbitration_id, msg.data)
    assert n > 1000
    assert {"MOTOR_CMD", "MOTOR_FB"} <= names


def test_record_into_a_missing_folder_is_refused_before_anything_starts(tmp_path):
    for command in (["sim", "--pty"], ["teleop", "/dev/null"]):
        done = run(ASPOD + command + ["--record", str(tmp_path / "no" / "x.pcapng")], text=True, timeout_s=60)
        assert done.returncode == 2 and "--record" in done.stderr and "no folder" in done.stderr
    done = run(ASPOD + ["sim", "--can-log", str(tmp_path / "x.pcap")], text=True, timeout_s=60)
    assert done.returncode == 2 and "--can-log" in done.stderr
