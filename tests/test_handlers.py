"""Command handlers beside their state, in one table per controller (firmware_py/handlers.py): two controllers in one
process each dispatch through their own, and a table that misses a command or handles one twice is refused by name."""
from __future__ import annotations

import inspect
from pathlib import Path

import pytest

from firmware_py.handlers import CommandOwner, handler_table, handles
from firmware_py.param_commands import ParamCommands
from host_tools.fuzz.coverage_report import HANDLER_FILES, ROOT
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason


@pytest.fixture
def two_worlds():
    """Two connected lock-step worlds in this process, each with its own controller."""
    worlds = [LockstepBench(seed=1), LockstepBench(seed=2)]
    try:
        assert all(world.connect() for world in worlds)
        yield worlds
    finally:
        for world in worlds:
            world.close()


def _param_list(world, index: int):
    handle = world.call(M["ParamList"](index))
    assert handle.reply is not None, handle.describe()
    return handle.reply


def test_a_handler_replaced_in_one_controller_s_table_leaves_the_other_s(two_worlds):
    first, second = two_worlds
    assert first.controller.handlers is not second.controller.handlers
    planted = first.controller.param_commands._param_value(Reason.BUSY, "planted")
    first.controller.handlers["ParamList"] = lambda msg, now: planted
    assert (_param_list(first, 0).result, _param_list(first, 0).name) == (Reason.BUSY, "planted")
    assert (_param_list(second, 0).result, _param_list(second, 0).name) == (
        Reason.OK, second.controller.params.order[0])


def test_a_handler_replaced_on_its_class_is_taken_by_controllers_built_after_and_only_by_them(monkeypatch):
    """The one way to replace a handler (a planted bug, a test): a plain function set on the owner's class before the
    controller is built. A controller built before keeps the handler it was built with."""
    before = LockstepBench(seed=1)
    after = None
    try:
        assert before.connect()

        def param_list(self, msg, now):
            return self._param_value(Reason.OUT_OF_RANGE, "planted")
        monkeypatch.setattr(ParamCommands, "_param_list", param_list)
        after = LockstepBench(seed=2)
        assert after.connect()
        assert (_param_list(after, 0).result, _param_list(after, 0).name) == (Reason.OUT_OF_RANGE, "planted")
        assert (_param_list(before, 0).result, _param_list(before, 0).name) == (
            Reason.OK, before.controller.params.order[0])
    finally:
        before.close()
        if after is not None:
            after.close()


class _Pings(CommandOwner):
    @handles("Ping")
    def _ping(self, msg, now):
        return M["Pong"](int(Reason.OK), msg.token, 0)


def test_a_command_handled_by_two_owners_is_refused_by_name():
    with pytest.raises(RuntimeError, match=r"command Ping is handled twice \(_Pings\._ping and _Pings\._ping\)"):
        handler_table([_Pings(), _Pings()])


def test_a_command_marked_twice_in_one_class_is_refused_by_name_when_the_class_is_made():
    with pytest.raises(TypeError, match=r"Twice: command Ping is handled twice \(_ping and _ping_again\)"):
        class Twice(CommandOwner):
            @handles("Ping")
            def _ping(self, msg, now):
                return None

            @handles("Ping")
            def _ping_again(self, msg, now):
                return None


def test_a_declared_command_without_a_handler_is_refused_by_name(bench):
    c = bench.controller
    with pytest.raises(RuntimeError) as raised:
        handler_table([c, c.arm_commands, c.param_commands])        # the tracker's commands left out
    assert str(raised.value) == "commands declared without a handler: BoxSwitch, BoxDial, GetBoxState, SetClock"


def test_a_handler_of_an_undeclared_message_is_refused_by_name():
    with pytest.raises(ValueError, match="no message 'Pingg' is declared in protocol/messages.py"):
        handles("Pingg")


def test_the_fuzz_coverage_report_counts_the_handlers_of_every_file_a_controller_s_table_takes_them_from(bench):
    owners = {type(handler.__self__) for handler in bench.controller.handlers.values()}
    files = {Path(inspect.getsourcefile(owner)).relative_to(ROOT) for owner in owners}
    assert files == {Path(f) for f in HANDLER_FILES}
