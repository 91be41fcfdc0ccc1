"""The command line at its edge: each command's Namespace becomes frozen settings once (host_tools/cli/settings.py);
a child `aspod plant` gets its command line back from them; --version, completion, logging, help."""
from __future__ import annotations

import dataclasses
import logging
import math
from datetime import datetime, timezone
from pathlib import Path

import pytest

from host_tools.cli.main import build_parser, main, setup_logging
from host_tools.cli.settings import (BusSettings, PlantRunSettings, demo_settings, firmware_settings,
                                     plant_run_settings, sim_settings, teleop_settings)
from host_tools.worlds.settings import PlantSettings

BUS = BusSettings("udp_multicast", "239.74.163.2", (("port", 43120), ("bitrate", 500000)))


def parse_plant(argv: list[str]) -> PlantRunSettings:
    return plant_run_settings(build_parser().parse_args(["plant", *argv]))


@pytest.mark.parametrize("settings", [
    PlantRunSettings(BUS),
    PlantRunSettings(BUS, PlantSettings(gravity="orbit", payload_kg=2.5,
                                        start=datetime(2026, 3, 20, 13, 50, 7, tzinfo=timezone.utc),
                                        clouds="12:00+300s@0.9,14:30+10m@0.5"),
                     seed=4294967295, timing="realtime", speed=math.inf, stop_on_stdin_eof=True),
    PlantRunSettings(BUS, PlantSettings(tracker=False, payload_kg=0.1), seed=7, speed=0.37, verbosity=2),
    PlantRunSettings(BusSettings("udp_multicast", "239.1.2.3"), PlantSettings(start=None, clouds="12:00+5m@0.5"),
                     verbosity=-1),
])
def test_plant_settings_to_argv_and_back_through_the_plant_parser_are_equal(settings):
    assert parse_plant(settings.to_argv()) == settings


def test_settings_are_frozen_and_validated():
    plant = PlantSettings()
    with pytest.raises(dataclasses.FrozenInstanceError):
        plant.gravity = "orbit"
    for bad in (dict(gravity="mars"), dict(payload_kg=-1.0), dict(payload_kg=math.nan),
                dict(tracker=False, clouds="12:00+5m@0.5"), dict(clouds="12:00+5m")):
        with pytest.raises(ValueError):
            PlantSettings(**bad)
    with pytest.raises(ValueError, match="resolve it"):
        PlantSettings(start=None).plant_start()
    with pytest.raises(ValueError, match="not one of"):
        PlantRunSettings(BUS, timing="sometimes")


def test_each_command_reads_its_namespace_once_into_settings():
    args = build_parser().parse_args(["sim", "--tcp", "0", "--baud", "9600", "--no-pacing", "--gravity", "orbit",
                                      "--payload-kg", "1.5", "--loop-hz", "500", "--seed", "3", "--speed", "max",
                                      "--sun-start", "2026-03-20T06:50-07:00"])
    sim = sim_settings(args)
    assert (sim.port.tcp, sim.port.device, sim.port.baud, sim.port.paced) == (0, None, 9600, False)
    assert sim.controller.gravity_m_s2 == 0.0 and sim.controller.loop_hz == 500.0 and sim.hal is None
    assert sim.plant == PlantSettings(gravity="orbit", payload_kg=1.5,
                                      start=datetime(2026, 3, 20, 13, 50, tzinfo=timezone.utc))
    assert sim.seed == 3 and sim.speed == math.inf
    fw = firmware_settings(build_parser().parse_args(
        ["firmware", "--interface", "udp_multicast", "--channel", "239.1.1.1", "--bus-arg", "port=43200",
         "--boot-timeout", "2", "--timing", "realtime"]))
    assert fw.bus == BusSettings("udp_multicast", "239.1.1.1", (("port", 43200),))
    assert fw.controller.boot_timeout_s == 2.0 and fw.controller.gravity_m_s2 is None and fw.timing == "realtime"
    demo = demo_settings(build_parser().parse_args(["demo", "--json", "--gravity", "orbit"]))
    assert (demo.json, demo.gravity, demo.link) == (True, "orbit", False)


def test_version_completion_and_help(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.startswith("aspod ")
    for shell, mark in (("bash", "complete"), ("zsh", "#compdef aspod")):
        assert main(["completion", shell]) == 0
        out = capsys.readouterr().out
        assert mark in out and "tracker-day" in out and "--sun-start" in out
    for argv in (["--help"], ["sim", "--help"], ["plant", "--help"]):
        with pytest.raises(SystemExit):
            main(argv)
        out = capsys.readouterr().out
        assert "examples:" in out and "exit status: 0 ok, 1 a command failed, 2 bad usage or input, 3 link" in out
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    assert "--gravity {earth,orbit}" in capsys.readouterr().out
    with pytest.raises(SystemExit) as done:
        main(["completion", "fish"])
    assert done.value.code == 2 and "invalid choice: 'fish'" in capsys.readouterr().err


def test_the_help_examples_name_only_files_the_repository_has():
    """A newcomer copies them: a script under benches/ that was renamed would fail at once."""
    from host_tools.cli.main import COMMANDS, EXAMPLES, command_module
    root = Path(__file__).resolve().parent.parent
    every = [EXAMPLES] + [command_module(module).EXAMPLES for _, _, module in COMMANDS]
    named = {word for lines in every for line in lines for word in line.split() if word.startswith("benches/")}
    assert named and sorted(w for w in named if not (root / w).is_file()) == []


def test_log_levels_and_the_log_file(tmp_path, capsys):
    log = logging.getLogger("aspod")
    try:
        setup_logging()
        log.info("aspod sim: uptime 5 ms: BOOT -> IDLE (OK), faults none")
        log.debug("hidden")
        assert capsys.readouterr().err == "aspod sim: uptime 5 ms: BOOT -> IDLE (OK), faults none\n"
        setup_logging(quiet=1, log_file=tmp_path / "aspod.log")
        log.info("quiet now")
        log.warning("a warning")
        assert capsys.readouterr().err == "a warning\n"
        kept = (tmp_path / "aspod.log").read_text()
        assert "WARNING a warning" in kept and "INFO quiet now" in kept     # -q quiets the terminal, not the file
        setup_logging(verbose=1)
        log.debug("shown")
        assert capsys.readouterr().err == "shown\n"
        args = build_parser(["demo"]).parse_args(["-v", "demo", "-q", "--log-file", "x.log"])
        assert (args.verbose, args.quiet, str(args.log_file)) == (1, 1, "x.log")
    finally:
        setup_logging()


def test_the_sims_control_endpoint_is_on_by_default_with_hal_too():
    def sim(*argv: str):
        return sim_settings(build_parser().parse_args(["sim", *argv]))
    assert (sim().control, sim().control_path) == (True, None)
    assert sim("--control", "/tmp/c.sock").control_path == Path("/tmp/c.sock")
    assert sim("--no-control").control is False
    assert sim("--hal", "udp_multicast").control is True           # it says the link's key; it reaches no plant
    assert sim("--hal", "udp_multicast", "--control", "/tmp/c.sock").control_path == Path("/tmp/c.sock")
    with pytest.raises(SystemExit):
        build_parser().parse_args(["sim", "--control", "/tmp/c.sock", "--no-control"])
    teleop = build_parser().parse_args(["teleop", "/dev/pts/3", "--control", "/tmp/c.sock"])
    assert teleop_settings(teleop).control == Path("/tmp/c.sock")


def test_hal_channel_and_hal_arg_without_hal_are_refused():
    """`aspod sim --hal-channel 239.1.1.1` (no --hal) ran the one-process world and said nothing of the channel."""
    def sim(*argv: str):
        return sim_settings(build_parser().parse_args(["sim", *argv]))
    with pytest.raises(ValueError, match="^--hal-channel without --hal"):
        sim("--hal-channel", "239.1.1.1")
    with pytest.raises(ValueError, match="^--hal-channel and --hal-arg without --hal"):
        sim("--hal-channel", "239.1.1.1", "--hal-arg", "port=45000")
    assert sim("--hal", "udp_multicast", "--hal-channel", "239.1.1.1").hal_channel == "239.1.1.1"


def test_a_fault_and_a_host_too_slow_are_warnings_that_quiet_still_shows(bench, capsys):
    """"World below real time" was INFO, so `-q` hid the one line that says the host is too slow."""
    from host_tools.cli.firmware import log_states
    from protocol.messages import MESSAGES as M
    from protocol.states import TimingIssue
    try:
        setup_logging(quiet=1)
        log_states(bench.controller, "aspod sim")
        say = bench.controller.report_listeners[-1]
        say(M["TimingWarning"](int(TimingIssue.BELOW_REAL_TIME), True, 0.4, 0.5, 1234))
        said = capsys.readouterr().err
        assert said.startswith("aspod sim: uptime 1234 ms:") and "0.4" in said, said
        say(M["TimingWarning"](int(TimingIssue.BELOW_REAL_TIME), False, 0.9, 0.5, 2234))
        assert capsys.readouterr().err == ""                          # its end is news, not a warning
    finally:
        setup_logging()
