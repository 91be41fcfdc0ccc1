"""Bad input at the real command line: files that are not files, numbers out of bounds, unknown keywords.

Everything runs the real `aspod` as a subprocess: what is refused exits 2 with a reason that
names the option and what was wrong, before anything starts; nothing hangs or fills memory
(every run has a time bound far above what a refusal takes, so that a hang fails the test
instead of stalling the suite).
"""
from __future__ import annotations

import os
import subprocess

import pytest
import test_e2e
from test_e2e import ASPOD, Sim

from firmware_py.params import PARAMS_FILE_LIMIT
from host_tools.teleop.words import SCRIPT_LIMIT
from host_tools.worlds.child import run
from protocol import auth, files

pytestmark = pytest.mark.pty
REFUSAL_S = 60.0      # of the child's own time: a refusal takes a second or two; a hang or an endless read, forever
NOWHERE = "socket://127.0.0.1:9"     # never reached: the input is refused before any connection
env = test_e2e.env                   # the fixture: a private per-user config directory


def aspod(env: dict, *args: str, stdin=subprocess.DEVNULL) -> subprocess.CompletedProcess:
    return run(ASPOD + list(args), env=env, stdin=stdin, timeout_s=REFUSAL_S)


def special_file(kind: str, tmp_path, limit: int) -> str:
    """A path that no input may be: an endless device, a FIFO, a directory, a regular file one byte too large."""
    if kind in ("/dev/zero", "/dev/urandom"):
        return kind
    path = tmp_path / kind
    if kind == "fifo":
        os.mkfifo(path)        # nobody ever writes to it: opening it for reading would wait forever
    elif kind == "directory":
        path.mkdir()
    else:
        path.write_bytes(b"#" * (limit + 1))
    return str(path)


KINDS = ("/dev/zero", "fifo", "directory", "too-large")
WHY = {"/dev/zero": "a character device, not a regular file", "/dev/urandom": "a character device, not a regular file",
       "fifo": "a FIFO (named pipe), not a regular file", "directory": "a directory, not a regular file",
       "too-large": "larger than"}


FILE_OPTIONS = [
    (("teleop", NOWHERE), "--key-file", auth.KEY_FILE_LIMIT),
    (("sim", "--tcp", "0"), "--key-file", auth.KEY_FILE_LIMIT),
    (("sim", "--tcp", "0"), "--params", PARAMS_FILE_LIMIT),
    (("teleop", NOWHERE), "--script", SCRIPT_LIMIT),
]


# Every kind for every option, and one more endless device (/dev/urandom) where a key or a script is read.
FILE_CASES = [(command, option, limit, kind) for command, option, limit in FILE_OPTIONS
              for kind in KINDS + (() if option == "--params" else ("/dev/urandom",))]


@pytest.mark.parametrize("command, option, limit, kind", FILE_CASES)
def test_a_file_input_that_is_not_a_small_regular_file_exits_2_naming_the_option_and_the_file(
        env, tmp_path, kind, command, option, limit):
    path = special_file(kind, tmp_path, limit)
    done = aspod(env, *command, option, path)
    err = done.stderr.decode()
    assert done.returncode == 2, err
    assert f"{option} {path}: {WHY[kind]}" in err
    if kind == "too-large":
        assert files.size_text(limit) in err
    assert "ASPOD-LINK" not in done.stdout.decode()       # nothing was started


def test_a_file_input_at_its_limit_is_read(tmp_path):
    path = tmp_path / "exact"
    path.write_bytes(b"x" * 1000)
    assert files.read_bounded(path, 1000) == b"x" * 1000
    with pytest.raises(files.InputFileError) as err:
        files.read_bounded(path, 999)
    assert err.value.refused and "larger than 999 bytes" in str(err.value)
    with pytest.raises(files.InputFileError) as err:
        files.read_bounded(tmp_path / "absent", 1000)
    assert err.value.missing and not err.value.refused


def test_an_endless_script_on_standard_input_is_refused(env):
    with open("/dev/zero", "rb") as endless:
        done = aspod(env, "teleop", NOWHERE, stdin=endless)
    assert done.returncode == 2
    assert f"standard input: larger than {files.size_text(SCRIPT_LIMIT)}" in done.stderr.decode()


def test_a_damaged_small_parameter_file_is_reported_and_the_defaults_stay(env, tmp_path):
    params = tmp_path / "params.json"
    params.write_text("{not json")
    sim = Sim(env, "--tcp", "0", "--params", str(params))
    try:
        done = sim.teleop("get telemetry_hz\n")
        assert done.returncode == 0, done.stderr.decode()
        assert "value=10.00" in done.stdout.decode()
    finally:
        _, err = sim.stop()
    assert f"parameters: {params}: Expecting property name" in err


# ---- teleop scripts: checked whole, fast, before anything is sent -------------------------------------------

def run_script(env: dict, script: str) -> subprocess.CompletedProcess:
    """A script on standard input against a URL nobody serves: a run that got past the check would exit 3."""
    return run(ASPOD + ["teleop", NOWHERE], input=script.encode(), env=env, timeout_s=REFUSAL_S)


def test_a_value_that_overflows_a_float32_is_refused_by_the_script_check(env):
    done = run_script(env, "estop\nset telemetry_hz 5\nset j1_kp 1e39\n")
    err = done.stderr.decode()
    assert done.returncode == 2, err
    assert "line 3: value=1e+39 does not fit in f32" in err and "nothing was sent" in err


def test_a_megabyte_word_is_refused_at_once_and_not_echoed_whole(env):
    from timebase import RealClock
    word = "x" * (3 << 20)                  # 3 MiB: shlex took minutes on it; the check refuses it by its length
    clock = RealClock()
    start = clock.now()
    done = run_script(env, f"ping\n{word}\n")
    took = clock.now() - start
    err = done.stderr.decode()
    assert done.returncode == 2, err[:500]
    assert "line 2: 'xxxx" in err and f"... ({len(word)} chars) is longer than any command" in err
    assert len(err) < 1000
    assert took < 30.0, f"{took:.1f} s to refuse it"     # a python start-up and a length check


@pytest.mark.parametrize("script, message", [
    ("ping\nhelp nosuch\n", "line 2: help: no command 'nosuch'"),
    ("help stauts\n", "(did you mean `status`?)"),
])
def test_help_on_an_unknown_topic_is_bad_input(env, script, message):
    done = run_script(env, script)
    assert done.returncode == 2 and message in done.stderr.decode(), done.stderr.decode()


# ---- numeric options name themselves and their bounds -------------------------------------------------------

@pytest.mark.parametrize("args, message", [
    (["sim", "--seed", "-1"], "argument --seed: -1 is outside 0..4294967295"),
    (["plant", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--seed", "4294967296"],
     "argument --seed: 4294967296 is outside 0..4294967295"),
    (["demo", "--seed", "many"], "argument --seed: 'many' is not a whole number in 0..4294967295"),
    (["tracker-day", "--seed", "-7"], "argument --seed: -7 is outside 0..4294967295"),
    (["sim", "--loop-hz", "nan"], "argument --loop-hz: nan is outside 50.0..5000.0"),
    (["sim", "--baud", "fast"], "argument --baud: 'fast' is not a whole number; one of 9600, 19200"),
    (["teleop", NOWHERE, "--connect-timeout", "soon"],
     "argument --connect-timeout: 'soon' is not a number in 0.1..600"),
    (["tracker-day", "--dial", "-5"], "--dial '-5': outside 0..100 %"),
    (["tracker-day", "--dial", "40,x"], "--dial '40,x': not a number of percent, 0..100"),
    (["tracker-day", "--param", "trk_deadband_mv=1e39"], "--param trk_deadband_mv=1e+39 outside 0..100 mV"),
])
def test_a_numeric_option_out_of_bounds_names_itself_and_its_bounds(env, args, message):
    done = aspod(env, *args)
    assert done.returncode == 2, done.stderr.decode()
    assert message in done.stderr.decode()


# ---- bus keywords: python-can would ignore a misspelt one ---------------------------------------------------

@pytest.mark.parametrize("args, message", [
    (["plant", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--bus-arg", "nonsense_kw=1"],
     "--bus-arg nonsense_kw: the udp_multicast bus takes no such keyword; it takes can_filters, config_context, "
     "fd, hop_limit, ignore_config, port, receive_own_messages"),
    (["firmware", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--bus-arg", "prot=5000"],
     "--bus-arg prot: the udp_multicast bus takes no such keyword"),
    (["sim", "--hal", "udp_multicast", "--hal-arg", "nonsense_kw=1"],
     "--hal-arg nonsense_kw: the udp_multicast bus takes no such keyword"),
])
def test_an_unknown_bus_keyword_is_refused_with_the_known_ones(env, args, message):
    done = aspod(env, *args)
    assert done.returncode == 2, done.stderr.decode()
    assert message in done.stderr.decode()


def test_bus_keywords_come_from_the_constructor_and_for_kwargs_buses_from_their_documentation():
    from host_tools.worlds import nodes
    assert {"port", "hop_limit", "fd", "can_filters"} <= nodes.bus_keywords("udp_multicast")
    assert "channel" not in nodes.bus_keywords("udp_multicast")
    assert {"device_id", "bitrate", "fd", "f_clock_mhz", "data_brp"} <= nodes.bus_keywords("pcan")   # fd: **kwargs
    assert nodes.parse_bus_args(["port=5000", "hop_limit=2"], "udp_multicast") == {"port": 5000, "hop_limit": 2}


def test_a_bus_whose_driver_fails_in_its_own_way_is_a_link_problem_not_a_crash(env):
    """python-can's kvaser bus without the vendor's canlib raises NameError; with it and no device, a CanError."""
    done = aspod(env, "firmware", "--interface", "kvaser", "--channel", "0")
    assert done.returncode == 3, done.stderr.decode()
    assert "cannot open the kvaser bus on channel '0'" in done.stderr.decode()
    assert "Traceback" not in done.stderr.decode()


# ---- link addresses: a scheme pyserial does not know is bad input, not a lost link -----------------------------

@pytest.mark.parametrize("args, option", [
    (["teleop", "bogus://x"], ""),
    (["teleop", f"radio={NOWHERE},optical=bogus://x"], ""),
    (["fuzz", "--url", "bogus://x", "--time", "1"], ""),
    (["proxy", "--controller", "bogus://x"], "--controller: "),
    (["proxy", "--controller", "pty", "--host", "bogus://x"], "--host: "),
    (["sim", "--port", "bogus://x"], "--port: "),
    (["sim", "--link", "radio=pty", "--link", "optical=bogus://x"], "--link optical: "),
])
def test_a_link_url_of_an_unknown_scheme_exits_2_naming_the_scheme_and_those_accepted(env, args, option):
    done = aspod(env, *args)
    err = done.stderr.decode()
    assert done.returncode == 2, err
    assert f"{option}bogus://x: unknown link scheme bogus://; a link is a device (/dev/pts/N) or a URL with one " \
           "of the schemes " in err
    assert "socket://" in err.split("schemes ")[1] and "rfc2217://" in err.split("schemes ")[1]
    assert "ASPOD-LINK" not in done.stdout.decode()        # nothing was opened or served


@pytest.mark.parametrize("url, said", [
    ("socket://127.0.0.1", "a socket link is socket://HOST:PORT, PORT a number 1..65535"),
    ("rfc2217://localhost", "an rfc2217 link is rfc2217://HOST:PORT, PORT a number 1..65535"),
])
def test_a_network_url_without_host_and_port_is_bad_input_too(env, url, said):
    done = aspod(env, "teleop", url)
    assert done.returncode == 2, done.stderr.decode()
    assert said in done.stderr.decode()


@pytest.mark.parametrize("options, message", [
    ({"fd": False}, "fd=False: the HAL bus is always CAN FD"),
    ({"can_filters": "x"}, "can_filters: the HAL nodes read every frame"),
    ({"receive_own_messages": True}, "receive_own_messages: a HAL node does not take its own frames"),
    ({"hop_limit": "abc"}, "udp_multicast: hop_limit 'abc' is not a whole number in 0..255"),
    ({"hop_limit": -1}, "udp_multicast: hop_limit -1 is not a whole number in 0..255"),
    ({"hop_limit": 999}, "udp_multicast: hop_limit 999 is not a whole number in 0..255"),
    ({"hop_limit": float("nan")}, "udp_multicast: hop_limit nan is not a whole number in 0..255"),
])
def test_bus_keywords_the_hal_cannot_work_with_are_refused_before_the_bus_opens(options, message):
    """--bus-arg fd=false opened a classic bus on which the plant could send no MOTOR_FB (it waited for ever,
    counting bus errors); can_filters=x opened the bus and crashed the node with a TypeError at its first frame;
    a bad hop_limit was exit 3, 'its python-can driver failed ...; is the vendor's library installed?'; and
    receive_own_messages=true exit 3, python-can's 'receiving own messages is not yet implemented'."""
    from host_tools.worlds import nodes
    with pytest.raises(ValueError) as refused:
        nodes.open_bus("udp_multicast", "239.74.200.99", node="PLANT", port=45099, **options)
    assert message in str(refused.value)


def test_a_udp_multicast_group_with_a_scope_is_refused_before_the_bus_opens():
    """'ff02::1%lo' passed the multicast check and failed in python-can's inet_pton: exit 3, 'could not create or
    configure socket (illegal IP address string passed to inet_pton)', as if the network were missing."""
    from host_tools.worlds import nodes
    with pytest.raises(ValueError, match="takes no scope"):
        nodes.open_bus("udp_multicast", "ff02::1%lo", node="PLANT", port=45099)
