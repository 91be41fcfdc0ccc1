"""`aspod sim --can-log` with `--can-only` / `--can-skip` (issue 36): the HAL bus log keeps the messages asked for,
read back by python-can; an unknown message is refused naming the ones there are. With `--can-rotate-mb`, in parts
within the size asked (a frame more at most), every frame in order across them, each put in place when full; the
parts' names claimed before the run; bad sizes refused (exit 2). All on the simulated clock."""
from __future__ import annotations

import os
import random

import can
import pytest

from host_tools.cli.main import build_parser
from host_tools.cli.settings import sim_settings
from host_tools.outputs import Claims, Output
from host_tools.sessions.capture import CAPTURE
from host_tools.worlds.can_log import KINDS, ROTATED, SizedRotatingLog, message_ids, part_names
from host_tools.worlds.world import LockstepBench
from protocol.hal import default_codec

IDS = {m.name: m.frame_id for m in default_codec().database.messages}


def _logged(tmp_path, ids) -> set[int]:
    bench = LockstepBench(seed=1)
    assert bench.connect()
    tmp_path.mkdir()
    path = tmp_path / "hal.blf"
    log = bench.world.log_hal_bus(Output(path, "--can-log", KINDS[".blf"]), ids)
    bench.run_for(0.2)
    bench.close()                       # the log closed and put in place with the world
    with can.BLFReader(str(path)) as reader:
        return {msg.arbitration_id for msg in reader} if log.frames else set()


def test_the_log_keeps_only_the_messages_asked_for(tmp_path):
    every = _logged(tmp_path / "a", None)
    assert {IDS["MOTOR_CMD"], IDS["MOTOR_FB"], IDS["ANALOG_IN"]} <= every
    slow = message_ids([], ["MOTOR_CMD", "MOTOR_FB", "PLANT_SYNC"])
    assert _logged(tmp_path / "b", slow) == every - {IDS["MOTOR_CMD"], IDS["MOTOR_FB"], IDS["PLANT_SYNC"]}
    assert _logged(tmp_path / "c", message_ids(["ANALOG_IN"], [])) == {IDS["ANALOG_IN"]}


def test_the_options_are_checked_against_the_dbc_before_the_run():
    def settings(*argv):
        return sim_settings(build_parser(["sim"]).parse_args(["sim", "--no-control", *argv]))
    assert settings("--can-log", "x.blf", "--can-only", "ANALOG_IN,DIGITAL_IN").can_ids == frozenset(
        {IDS["ANALOG_IN"], IDS["DIGITAL_IN"]})
    assert settings("--can-log", "x.blf").can_ids is None
    with pytest.raises(ValueError, match="--can-skip MOTOR_CMND: no such message in protocol/hal.dbc; one of .*MOTOR_CMD"):
        settings("--can-log", "x.blf", "--can-skip", "MOTOR_CMND")
    with pytest.raises(ValueError, match="only with --can-log"):
        settings("--can-only", "ANALOG_IN")


# ---- --can-rotate-mb: python-can's SizedRotatingLogger, its parts put in place one by one ------------------------

def _frames(paths) -> list[tuple]:
    """Every frame of `paths`, in order, as python-can reads them back."""
    frames = []
    for path in paths:
        with can.LogReader(str(path)) as reader:
            frames += [(round(m.timestamp, 6), m.arbitration_id, bytes(m.data), m.channel) for m in reader]
    return frames


def _world_log(path, rotate_bytes=None, run_s=1.0, close=True):
    """0.5 s of the world before the log begins, `run_s` logged (the same frames for the same seed)."""
    bench = LockstepBench(seed=3)
    bench.run_for(0.5)
    log = bench.world.log_hal_bus(Output(path, "--can-log", KINDS[path.suffix]), None, rotate_bytes)
    bench.run_for(run_s)
    if close:
        bench.close()
    return bench, log


@pytest.mark.parametrize("suffix", [".log", ".blf", ".asc"])
def test_a_rotated_log_is_parts_within_the_bound_holding_every_frame_in_order(tmp_path, suffix):
    bound = {".log": 60_000, ".blf": 20_000, ".asc": 80_000}[suffix]
    _, whole = _world_log(tmp_path / f"whole{suffix}")
    _, log = _world_log(tmp_path / f"hal{suffix}", bound)
    assert len(log.parts) >= 3
    assert [p.name for p in log.files] == [f"hal_#{n:03}{suffix}" for n in range(len(log.parts))] + [f"hal{suffix}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f"whole{suffix}"] + [p.name for p in log.files])
    if suffix == ".blf":        # python-can counts the frames it has not compressed yet at their full size
        slack = 0
    else:                       # a part is closed once it holds the bound: at most one frame (a line) more
        slack = max(len(line) for line in (tmp_path / f"whole{suffix}").read_bytes().splitlines(keepends=True))
    for path in log.files:
        assert 0 < path.stat().st_size <= bound + slack, path
    every = _frames([tmp_path / f"whole{suffix}"])
    if suffix in (".blf", ".asc"):      # their times count from the file's first frame (python-can's writers)
        parts, start = [], 0
        for path in log.files:
            frames = _frames([path])
            parts += [(round(t - frames[0][0] + every[start][0], 6), *rest) for t, *rest in frames]
            start += len(frames)
        assert parts == every
    else:
        assert _frames(log.files) == every
    assert len(every) == log.frames == whole.frames


def test_a_rotated_run_that_never_ends_leaves_its_full_parts_and_the_destination_as_it_was(tmp_path):
    """Killed outright, nothing more is done: the parts finished are in place and readable, the frames after them in
    the temporary, the destination what it was."""
    path = tmp_path / "hal.log"
    path.write_bytes(b"(0.000000) plant 123#01 R\n")
    path.chmod(0o640)
    bench, log = _world_log(path, 50_000, close=False)
    assert len(log.parts) >= 2 and path.read_bytes() == b"(0.000000) plant 123#01 R\n"
    (left,) = [p for p in tmp_path.iterdir() if ".part" in p.name]
    assert left.name.startswith(".hal.log.") and left.name.endswith(".part.log")
    assert len(_frames(log.parts)) < log.frames
    bench.close()                 # (ended after all: the last part in place, with the mode the file had)
    assert len(_frames(log.files)) == log.frames
    umask = os.umask(0o022)
    os.umask(umask)
    assert {p.stat().st_mode & 0o777 for p in log.parts} == {0o666 & ~umask} and path.stat().st_mode & 0o777 == 0o640


def test_python_can_rotates_what_rotated_says():
    assert set(ROTATED) == can.SizedRotatingLogger._supported_formats & set(KINDS)


def _sim(*argv):
    return sim_settings(build_parser(["sim"]).parse_args(["sim", "--no-control", *argv]))


def test_the_parts_are_claimed_before_the_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert _sim("--can-log", "hal.log", "--can-rotate-mb", "2.5").can_rotate_bytes == 2_500_000
    assert _sim("--can-log", "hal.log").can_rotate_bytes is None
    assert _sim("--can-log", "hal.log", "--can-rotate-mb", "1e-9").can_rotate_bytes == 1     # (0 is no rotation)
    with pytest.raises(ValueError, match=r"--can-rotate-mb: only with --can-log"):
        _sim("--can-rotate-mb", "5")
    with pytest.raises(ValueError, match=r"--can-log hal.trc with --can-rotate-mb: python-can rotates .asc, .blf"):
        _sim("--can-log", "hal.trc", "--can-rotate-mb", "5")
    with pytest.raises(ValueError, match=r"--can-log hal.log: its parts are named hal_#NNN.log, and hal_#000.log is "
                                         r"where --record writes"):
        _sim("--record", "hal_#000.log", "--can-log", "hal.log", "--can-rotate-mb", "5")
    with pytest.raises(ValueError, match=r"--can-log hal.log: its parts are named hal_#NNN.log, and .*hal_#001.log "
                                         r"is the key file \(--key-file\), an input of this run"):
        (tmp_path / "hal_#001.log").write_bytes(b"")
        _sim("--key-file", "hal_#001.log", "--can-log", "hal.log", "--can-rotate-mb", "5")
    (tmp_path / "hal_#000.log").write_bytes(b"(1.000000) plant 123#01 R\n")
    for force in ([], ["--force"]):          # an earlier run's parts: never replaced, nor mixed with this run's
        with pytest.raises(ValueError, match=r"--can-log hal.log: its parts are named hal_#NNN.log, and "
                                             r".*hal_#000.log is there already \(and 1 more\); parts are never replaced"):
            sim_settings(build_parser(["sim"]).parse_args([*force, "sim", "--no-control", "--can-log", "hal.log",
                                                            "--can-rotate-mb", "5"]))
    assert _sim("--can-log", "other.log", "--can-rotate-mb", "5").can_log.path.name == "other.log"
    assert _sim("--can-log", "hal.log").can_log                       # one file: as before, over hal.log
    outputs = Claims([])                 # an output claimed after the parts (aspod sim claims --can-log last)
    rotated = outputs.file(tmp_path / "other.log", "--can-log", KINDS[".log"])
    outputs.series(rotated, part_names(rotated.destination), "other_#NNN.log")
    with pytest.raises(ValueError, match=r"--record .*other_#004.log: --can-log writes its parts there "
                                         r"\(other_#NNN.log\)"):
        outputs.file(tmp_path / "other_#004.log", "--record", CAPTURE)


def test_bad_sizes_and_the_option_alone_are_refused_with_exit_2(tmp_path, monkeypatch, capsys, caplog):
    from host_tools.cli import main as cli_main, sim
    monkeypatch.setattr(sim, "run_sim", lambda settings: pytest.fail("ran"))
    monkeypatch.setattr(cli_main, "setup_logging", lambda *a, **k: None)
    log = str(tmp_path / "hal.log")
    for size, said in (("0", "0.0 is not a finite number above 0"), ("-1", "-1.0 is not a finite number above 0"),
                       ("inf", "inf is not a finite number above 0"), ("nan", "nan is not a finite number above 0"),
                       ("5MB", "'5MB' is not a number above 0")):
        with pytest.raises(SystemExit) as done:
            cli_main.main(["sim", "--no-control", "--can-log", log, "--can-rotate-mb", size])
        assert done.value.code == 2
        assert f"argument --can-rotate-mb: {said}" in capsys.readouterr().err
    assert cli_main.main(["sim", "--no-control", "--can-rotate-mb", "5"]) == 2
    assert "aspod: --can-rotate-mb: only with --can-log" in caplog.text
    assert not (tmp_path / "hal.log").exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".log", ".csv", ".blf", ".txt"])
def test_looking_at_the_size_less_often_rotates_before_the_same_frames_as_python_can(tmp_path, suffix):
    rng = random.Random(7)
    frames = [can.Message(timestamp=n * 1e-4, arbitration_id=rng.randrange(0x800), is_fd=n % 3 == 0,
                          data=rng.randbytes(rng.choice((0, 8, 64) if n % 3 == 0 else (0, 3, 8))), channel="plant")
              for n in range(6000)]
    parts = {}
    for cls in (can.SizedRotatingLogger, SizedRotatingLog):
        folder = tmp_path / cls.__name__
        folder.mkdir()
        logger = cls(str(folder / f"hal{suffix}"), max_bytes=25_000)
        logger.namer = lambda default, logger=logger, folder=folder: str(folder / f"{logger.rollover_count}{suffix}")
        for msg in frames:
            logger.on_message_received(msg)
        logger.stop()
        parts[cls] = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert len(parts[SizedRotatingLog]) >= 5
    assert parts[SizedRotatingLog] == parts[can.SizedRotatingLogger]


@pytest.mark.parametrize("suffix", ROTATED)
def test_no_format_writes_a_frame_of_frame_bytes_max_or_more(tmp_path, suffix):
    widest = can.Message(timestamp=12345.678901, arbitration_id=0x1FFFFFFF, is_extended_id=True, is_fd=True,
                         bitrate_switch=True, error_state_indicator=True, data=bytes(range(64)), channel="controller")
    writer = can.Logger(str(tmp_path / f"x{suffix}"))
    writer.on_message_received(widest)
    sizes = [writer.file_size()]
    for _ in range(3):
        writer.on_message_received(widest)
        sizes.append(writer.file_size())
    writer.stop()
    assert max(b - a for a, b in zip(sizes, sizes[1:])) < SizedRotatingLog.FRAME_BYTES_MAX / 2
