"""A light start: `aspod --version` and `--help` build only the parser they need, and `aspod sim` starts without
pandas or pvlib (the plant's sun is hil_sim/spa.py's). The times and the memory are bench/bench_start.py's."""
from __future__ import annotations

import importlib.metadata
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools.cli.main import COMMANDS, build_parser, command_word, installed_version, main
from host_tools.worlds.child import Child

ROOT = Path(__file__).resolve().parent.parent
HEAVY = ("numpy", "hil_sim.plant", "firmware_py.controller", "host_tools.worlds.world", "pandas", "pvlib")
# In a child: `aspod ARGS`, then the heavy modules it left imported, on stderr.
AFTER = ("import json, sys\nfrom host_tools.cli.main import main\ntry:\n    main(sys.argv[1:])\n"
         f"except SystemExit:\n    pass\nprint(json.dumps([m for m in {HEAVY!r} if m in sys.modules]), file=sys.stderr)\n")


def heavy_after(*argv: str) -> tuple[str, list[str]]:
    done = subprocess.run([sys.executable, "-c", AFTER, *argv], capture_output=True, text=True, cwd=ROOT, timeout=120)
    return done.stdout, json.loads(done.stderr.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", [["--version"], ["--help"], ["-v", "--help"], ["teleop", "--help"],
                                  ["log", "--help"]])
def test_version_and_help_load_neither_numpy_nor_the_plant(argv):
    out, heavy = heavy_after(*argv)
    assert heavy == [], heavy
    assert out.startswith("aspod " if argv == ["--version"] else "usage: aspod"), out


def test_the_version_is_the_installed_metadatas():
    assert installed_version() == importlib.metadata.version("aspod")
    assert heavy_after("--version")[0].strip() == f"aspod {importlib.metadata.version('aspod')}"


def test_the_version_of_a_distribution_that_is_not_installed():
    assert installed_version("no-such-aspod-distribution") == "unknown (not installed)"


@pytest.mark.parametrize("argv, word", [
    (["sim", "--pty"], "sim"), (["-v", "-q", "demo", "--json"], "demo"), (["--log-file", "sim", "teleop", "x"], "teleop"),
    (["--log", "sim.log", "bench", "s.txt"], "bench"), (["--log-file=x.log", "plan"], "plan"), (["--version"], None),
    ([], None), (["simulate"], None), (["-vv", "tracker-day"], "tracker-day")])
def test_the_command_word_is_found_past_the_options_before_it(argv, word):
    assert command_word(argv) == word


def test_a_command_parses_alone_as_with_every_command():
    every = build_parser()
    for argv in (["sim", "--tcp", "0", "--gravity", "orbit", "--seed", "7", "--clouds", "12:00+300s@0.9"],
                 ["-v", "plant", "--interface", "udp_multicast", "--channel", "239.74.163.2", "--payload-kg", "2"],
                 ["demo", "--json", "--gravity", "orbit"], ["teleop", "/dev/pts/3", "--baud", "9600"],
                 ["--log-file", "x.log", "bench", "s.txt", "--fault", "jam:j2@3.5"]):
        word = command_word(argv)
        alone = build_parser(only=(word,))
        assert vars(alone.parse_args(argv)) == vars(every.parse_args(argv)), argv
    sub = {name: p for a in every._actions if a.dest == "command" for name, p in a.choices.items()}
    for name, _, _ in COMMANDS:         # each command's help, built alone, is the one the whole parser has
        alone = [a for a in build_parser(only=(name,))._actions if a.dest == "command"][0].choices[name]
        assert alone.format_help() == sub[name].format_help(), name


def test_an_unknown_command_is_refused_as_before(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["simulate", "--pty"])
    assert stop.value.code == 2
    assert "invalid choice: 'simulate'" in capsys.readouterr().err


@pytest.mark.pty
def test_aspod_sim_starts_without_pandas_or_pvlib(tmp_path):
    """Up to its ready lines `aspod sim` imports neither (pvlib's import was 71 % of its start's imports) and holds
    at most 120 MiB (it held 225)."""
    importtime = tmp_path / "importtime.txt"
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}
    with importtime.open("w") as stderr:
        sim = Child(["sim", "--tcp", "0"], env=env, stderr=stderr,
                    command=(sys.executable, "-X", "importtime", "-m", "host_tools.cli.main"))
        try:
            for prefix in ("ASPOD-LINK ", "ASPOD-KEY ", "ASPOD-CONTROL "):
                sim.ready(prefix, timeout_s=120.0)
            with open(f"/proc/{sim.pid}/status") as status:
                peak_mib = next(int(line.split()[1]) for line in status if line.startswith("VmHWM:")) / 1024
        finally:
            sim.stop()
    imported = {line.split("|")[2].strip() for line in importtime.read_text().splitlines()
                if line.startswith("import time:")}
    assert not imported & {"pandas", "pvlib", "scipy", "matplotlib"}, sorted(imported & {"pandas", "pvlib", "scipy"})
    assert "hil_sim.spa" in imported and "numpy" in imported
    assert peak_mib <= 120, peak_mib


@pytest.mark.parametrize("argv", [["sim", "--bogus"], ["log", "x.pcapng", "--nope", "1"], ["-v", "teleop", "u", "-Z"]])
def test_an_unknown_option_is_refused_with_its_commands_usage(argv, capsys):
    """argparse says an option no parser took with the top-level usage (`usage: aspod [-h] ...`); a user who
    mistyped an option of `aspod sim` wants sim's."""
    command = next(word for word in argv if not word.startswith("-"))
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err
    assert stop.value.code == 2
    assert err.startswith(f"usage: aspod {command} ") and f"aspod {command}: error: unrecognized arguments:" in err, err
