"""Docs and teleop derive from the one declaration, and stay in step with it."""
from __future__ import annotations

from pathlib import Path

import pytest

from host_tools.teleop import session as teleop
from protocol import docgen
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.schema import Direction, MsgClass
from protocol.states import Fault

ROOT = Path(__file__).resolve().parent.parent


def test_protocol_doc_is_generated_from_the_declaration():
    committed = (ROOT / "docs" / "protocol.md").read_text()
    assert committed == docgen.render(), "docs/protocol.md is stale: run `make docs`"


def test_protocol_doc_lists_every_message_reason_and_fault():
    text = docgen.render()
    for spec in SCHEMA.by_id.values():
        assert f"### {spec.name}" in text
        for fld in spec.fields:
            assert f"`{fld.name}`" in text
    for reason in Reason:
        assert f"`{reason.name}`" in text and reason.remedy in text
    for fault in Fault:
        if fault:
            assert f"`{fault.name}`" in text


def test_teleop_words_are_the_declared_commands():
    declared = {s.teleop for s in SCHEMA.by_id.values() if s.teleop}
    assert set(teleop.commands()) == declared
    assert {"ping", "status", "estop", "reset"} <= declared
    for spec in teleop.commands().values():
        assert spec.direction is Direction.TO_CONTROLLER and spec.cls in (MsgClass.COMMAND, MsgClass.URGENT)
    assert set(teleop.all_words()) == declared | set(teleop.LOCAL_COMMANDS)


def test_teleop_builds_messages_from_field_declarations():
    step = teleop.parse_line("telemetry rate_hz=25", 1)
    assert step.message == SCHEMA["SetTelemetryRate"].type(25)
    assert teleop.parse_line("telemetry 0x10", 1).message.rate_hz == 16
    assert teleop.parse_line("ping", 1).message == SCHEMA["Ping"].type(0)     # declared default
    assert teleop.parse_line("  # a comment", 1) is None


@pytest.mark.parametrize("line, words", [
    ("telemetry 500", ["rate_hz=500", "outside [0, 200]"]),
    ("telemetry fast", ["rate_hz", "'fast'"]),
    ("telemetry", ["needs rate_hz"]),
    ("ping 1 2", ["takes 1 argument"]),
    ("ping colour=red", ["no argument 'colour'"]),
    ("warp 9", ["line 7: unknown command 'warp'"]),
    ("wait forever", ["not a number of seconds"]),
    ("wait j1 soon", ["timeout", "'soon' is not a number of seconds"]),
    ("wait j7 5", ["'j7' is not an axis"]),
    ("wait all 5 6", ["at most an axis and a timeout"]),
    ("wait 5000", ["outside 0..3600"]),
    ("watch later", ["watch", "not a number of seconds"]),
    ("move elbow 3", ["axis", "one of j1, j2, j3, j4, gripper, mount, all"]),
    ("move j1 400", ["target=400.0 is outside [-360.0, 360.0] deg"]),
    ("grip tight", ["one of open, close"]),
    ('ping "unclosed', ["line 7"]),
    ("set j1_kp 1e39", ["value=1e+39 does not fit in f32"]),         # finite, but not as a float32 on the wire
    ("set j1_kp -4e38", ["does not fit in f32"]),
    ("help nosuch", ["help: no command 'nosuch'", "`help` lists them all"]),
    ("help pnig", ["did you mean `ping`?"]),
    ("frobnicat", ["unknown command 'frobnicat'"]),
    ("staus", ["did you mean `status`?"]),
    ("get " + "x" * 5000, ["'get xxxx", "... (5004 chars) is longer than any command", "at most 1024"]),
    ("get " + "x" * 500, ["name: 'xxxx", "... (500 chars) is not a valid str16"]),
    ("ping 0x" + "f" * 200, ["token: '0xff", "... (202 chars) is not a valid u32"]),
])
def test_teleop_refuses_bad_lines_with_a_reason(line, words):
    with pytest.raises(teleop.TeleopError) as err:
        teleop.parse_line(line, 7)
    for word in words:
        assert word in str(err.value)
    assert len(str(err.value)) < 400          # a long word is not echoed whole


def test_a_comment_may_be_long_and_a_script_check_stops_after_its_first_problems():
    assert teleop.parse_line("ping  # " + "x" * 100_000, 1).message == SCHEMA["Ping"].type(0)
    steps, problems = teleop.check_script(["warp 9"] * 1000)
    assert len(problems) == 51 and problems[-1] == "checking stopped at line 50 of 1000 after 50 problems"


def test_a_script_is_checked_whole_before_anything_runs():
    steps, problems = teleop.check_script(["ping", "estop", "fly", "reset", "telemetry 999"])
    assert len(steps) == 3
    assert [p.split(":")[0] for p in problems] == ["line 3", "line 5"]


def test_help_lists_every_command_once_by_job_and_describes_one_in_a_users_words():
    from host_tools.teleop.words import INDEX
    lines = teleop.help_text().split("\n")
    jobs = [line for line in lines if line and not line.startswith(" ")][1:-1]     # between the title and the rules
    assert jobs == ["arm", "tracker", "controller", "link", "simulator", "console"]
    listed = [line.split()[0] for line in lines if line.startswith("  ") and not line.startswith("   ")]
    assert sorted(listed) == sorted(teleop.all_words()) and len(set(listed)) == len(listed)
    assert [w for _job, words in INDEX for w, _what in words] == listed
    move = teleop.help_text("move")
    assert move.split("\n")[0] == "move AXIS TARGET [SPEED]"
    assert "TARGET   a number of degrees, from -360 to 360" in move and "f32" not in move
    assert "AXIS     j1, j2, j3, j4 or mount\n" in move                 # one list: the axes move takes
    assert "AXIS   j1, j2, j3, j4, gripper, mount or all" in teleop.help_text("home")
    assert "a whole number of times a second, from 0 to 200" in teleop.help_text("telemetry")
    assert "if left out, both" in teleop.help_text("dial")


def test_wait_waits_for_motions_or_pauses():
    from protocol.states import Axis
    assert (teleop.parse_line("wait", 1).axis, teleop.parse_line("wait", 1).seconds) == (Axis.ALL, 120.0)
    step = teleop.parse_line("wait j1 5", 1)
    assert step.waits_for_motion and (step.axis, step.seconds) == (Axis.J1, 5.0)
    assert teleop.parse_line("wait gripper", 1).axis == Axis.GRIPPER
    step = teleop.parse_line("wait 2.5", 1)
    assert not step.waits_for_motion and step.seconds == 2.5        # a pause, as before
    assert "wait [AXIS|all] [TIMEOUT]" in teleop.help_text("wait")


def test_motion_words_take_declared_enum_values_and_complete_them():
    from host_tools.teleop.words import completions
    assert teleop.parse_line("home", 1).message == SCHEMA["Home"].type(255)          # declared default: all
    assert teleop.parse_line("grip close", 1).message.action == 1
    assert teleop.parse_line("move mount -2.5", 1).message == SCHEMA["Move"].type(5, -2.5, 0.0)
    assert completions("mo", 0, "mo") == ["move", "moveby"]
    assert completions("move ", 5, "") == ["j1", "j2", "j3", "j4", "gripper", "mount", "all"]
    assert completions("grip c", 5, "c") == ["close"]
    assert completions("wait g", 5, "g") == ["gripper"]
    assert "j1, j2, j3, j4 or mount" in teleop.help_text("move")        # the axes move takes, not the enum
