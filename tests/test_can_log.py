"""`aspod sim --can-log` with `--can-only` / `--can-skip` (issue 36): the HAL bus log keeps the messages asked for,
read back by python-can; an unknown message is refused naming the ones there are."""
from __future__ import annotations

import can
import pytest

from host_tools.cli.main import build_parser
from host_tools.cli.settings import sim_settings
from host_tools.outputs import Output
from host_tools.worlds.can_log import KINDS, message_ids
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
