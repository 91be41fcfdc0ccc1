"""Output files (host_tools/outputs.py): never over an input of the run, checked before the work, written whole.

The cases the issue names run the real `aspod` as a subprocess: `aspod sim --record KEYFILE`, `aspod teleop
--record SCRIPT`, `aspod proxy --record PARAMS` are refused (exit 2) and the file is kept to the byte. The rest
goes through the settings (`host_tools/cli/settings.py`) and `Pending` itself, and through live runs stopped by
SIGTERM, SIGINT and SIGKILL.
"""
from __future__ import annotations

import os
import re
import signal
import stat
import subprocess
from pathlib import Path

import can
import pytest

from host_tools.apps.script_bench import run_script_bench
from host_tools.cli import settings
from host_tools.cli.main import build_parser
from host_tools.client.live import HostClient
from host_tools.outputs import Claims, Kind, Output, begins, unclaimed
from host_tools.sessions.capture import CAPTURE, CaptureWriter, SessionInfo
from host_tools.worlds.bench_world import WorldSettings
from host_tools.worlds.child import Child, ChildError
from protocol import auth
from protocol.messages import MESSAGES as M
from protocol.schema import Direction
from test_e2e import ASPOD
from tests.captures import read_capture, read_frames

REFUSAL_S = 60.0      # a refusal takes a second or two; a command that runs instead would run until stopped
NOWHERE = "socket://127.0.0.1:9"     # never reached: the output is refused before any connection
UNWRITABLE = "/proc"                 # a folder no process can make a file in, root or not


@pytest.fixture
def home(tmp_path):
    """A private config folder with a key of the user's and a saved parameter file; (env, key, params)."""
    key = tmp_path / "config" / "aspod" / "link.key"
    auth.write_key(key, auth.new_nonce() + auth.new_nonce())
    params = key.with_name("params.json")
    params.write_text('{"link_timeout_s": 3.0}\n')
    return {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}, key, params


def aspod(env: dict, *args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(ASPOD + list(args), capture_output=True, text=True, env=env, cwd=cwd,
                          stdin=subprocess.DEVNULL, timeout=REFUSAL_S)


def refused(done: subprocess.CompletedProcess, option: str, path, said: str) -> None:
    assert done.returncode == 2, done.stderr
    assert f"{option} {path}: {said}" in done.stderr, done.stderr
    assert "ASPOD-LINK" not in done.stdout and "Traceback" not in done.stderr


def kept(path: Path, before: bytes) -> None:
    assert path.read_bytes() == before
    assert [p.name for p in path.parent.iterdir() if ".part" in p.name] == []       # no temporary left either


# ---- the cases, through the real command line ------------------------------------------------------------

def test_sim_record_onto_its_key_file_or_parameter_file_by_any_name_is_refused_and_the_key_kept(home, tmp_path):
    env, user_key, params = home
    key = tmp_path / "link.key"
    auth.write_key(key, auth.new_nonce() + auth.new_nonce())
    os.link(key, tmp_path / "hard.pcapng")
    os.symlink(key, tmp_path / "soft.pcapng")
    before = {p: p.read_bytes() for p in (key, user_key, params)}
    for args, record, said in (
            (["--key-file", str(key)], key, "that is the key file (--key-file)"),
            (["--key-file", str(key)], tmp_path / "hard.pcapng", "that is the key file (--key-file)"),
            (["--key-file", str(key)], tmp_path / "soft.pcapng", "that is the key file (--key-file)"),
            (["--params", str(params)], params, "that is the parameter file (--params)"),
            ([], params.parent / ".." / "aspod" / "params.json", "that is the parameter file")):
        done = aspod(env, "sim", "--tcp", "0", "--no-control", *args, "--record", str(record))
        refused(done, "--record", record, said)
        assert "an input of this run" in done.stderr
    for path, data in before.items():
        kept(path, data)


def test_teleop_record_onto_its_script_or_key_is_refused_and_both_kept(home, tmp_path):
    env, user_key, _ = home
    script = tmp_path / "session.aspod"
    script.write_text("ping\nstatus\n")
    before = {script: script.read_bytes(), user_key: user_key.read_bytes()}
    for args, record, said in ((["--script", str(script)], script, "that is the script"),
                               (["--key-file", str(user_key), "--script", str(script)], user_key, "that is the key file")):
        refused(aspod(env, "teleop", NOWHERE, *args, "--record", str(record)), "--record", record, said)
    for path, data in before.items():
        kept(path, data)


def test_proxy_record_onto_the_parameter_file_or_its_key_is_refused_and_both_kept(home):
    """The proxy's controller endpoint is one it serves (tcp:0), so on the code before this the capture was made at
    once, over the file."""
    env, user_key, params = home
    before = {params: params.read_bytes(), user_key: user_key.read_bytes()}
    for args, record, said in (([], params, "that is the parameter file"),
                               (["--key-file", str(user_key)], user_key, "that is the key file (--key-file)")):
        done = aspod(env, "proxy", "--controller", "tcp:0", "--host", "tcp:0", "--no-view", *args,
                     "--record", str(record))
        refused(done, "--record", record, said)
    for path, data in before.items():
        kept(path, data)


def test_a_log_file_onto_the_key_is_refused_and_the_key_kept(home, tmp_path):
    """--log-file appends: on the code before this the key file got log lines and no longer loaded."""
    env, user_key, _ = home
    before = user_key.read_bytes()
    refused(aspod(env, "--log-file", str(user_key), "sim", "--tcp", "0", "--no-control", "--key-file", str(user_key)),
            "--log-file", user_key, "that is the key file (--key-file)")
    refused(aspod(env, "teleop", NOWHERE, "--key-file", str(user_key), "--log-file", str(user_key)), "--log-file",
            user_key, "that is the key file (--key-file)")
    kept(user_key, before)
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    refused(aspod(env, "--log-file", str(notes), "wireshark"), "--log-file", notes,
            "an existing file that is not a log file of aspod's")
    assert notes.read_text() == "my notes\n"
    assert aspod(env, "--log-file", str(notes), "--force", "wireshark").returncode == 0     # appended to, as asked
    assert notes.read_text().startswith("my notes\n")


def test_an_existing_file_that_is_not_a_capture_is_overwritten_only_with_force(home, tmp_path):
    env, _, _ = home
    script, notes, capture = tmp_path / "s.aspod", tmp_path / "notes.txt", tmp_path / "old.pcapng"
    script.write_text("status\n")
    notes.write_text("my notes\n")
    refused(aspod(env, "bench", str(script), "--record", str(notes)), "--record", notes,
            "an existing file that is not a pcapng capture; --force overwrites it")
    kept(notes, b"my notes\n")
    assert aspod(env, "bench", str(script), "--record", str(capture)).returncode == 0       # a new one
    assert aspod(env, "bench", str(script), "--record", str(capture)).returncode == 0       # a capture over a capture
    done = aspod(env, "bench", str(script), "--record", str(notes), "--force")
    assert done.returncode == 0, done.stderr
    assert read_frames(notes) and read_frames(capture)


def test_outputs_that_cannot_be_written_are_refused_before_the_work_not_after_it_with_a_raw_errno(home):
    """On the code before this the day, the plan and the simulator ran, and then failed on the file (exit 3,
    `[Errno 2] No such file or directory`)."""
    env, _, _ = home
    for args, option, path, said in (
            (["tracker-day", "--from", "12:00", "--to", "12:10"], "--plot", f"{UNWRITABLE}/day.png", "cannot be written"),
            (["plan", "--nodes", "100"], "--plot", f"{UNWRITABLE}/figures", "cannot be made in /proc"),
            (["wireshark"], "--output", f"{UNWRITABLE}/aspod.lua", "cannot be written in /proc"),
            (["sim", "--tcp", "0", "--no-control"], "--record", f"{UNWRITABLE}/s.pcapng", "cannot be written"),
            (["sim", "--tcp", "0", "--no-control"], "--can-log", f"{UNWRITABLE}/bus.blf", "cannot be written"),
            (["sim", "--tcp", "0", "--no-control"], "--record", "/no/such/folder/s.pcapng", "no folder /no/such")):
        done = aspod(env, *args, option, path)
        refused(done, option, path, said)
        assert done.stdout == ""                                             # nothing ran


# ---- live captures: stopped, they are put in place whole; killed, the destination stays ------------------------

def _sim(env: dict, key: Path, *args: str) -> tuple[Child, str]:
    sim = Child(["sim", "--tcp", "0", "--no-control", "--key-file", str(key), *args], env=env)
    try:
        link = sim.line(60.0)
        sim.line(60.0)                           # ASPOD-KEY
    except ChildError as exc:
        sim.stop()
        raise AssertionError(str(exc)) from None
    assert link.startswith("ASPOD-LINK "), link
    return sim, link.split(" ", 1)[1]


def _ping(url: str, key: Path) -> None:
    client = HostClient(url, auth.load_key(key))
    try:
        client.connect(30.0)
        assert client.call(M["Ping"](7)).ok
    finally:
        client.close()


def _temporaries(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if ".part" in p.name)


@pytest.mark.pty
@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_a_live_capture_stopped_by_a_signal_is_put_in_place_whole(home, tmp_path, stop):
    env, key, _ = home
    earlier = tmp_path / "s.pcapng"
    earlier.write_bytes(b"")
    sim, url = _sim(env, key, "--record", str(earlier), "--can-log", str(tmp_path / "bus.asc"))
    try:
        assert [p.name.split(".")[1] for p in _temporaries(tmp_path)] == ["bus", "s"]     # written beside them
        _ping(url, key)
    finally:
        status, err = sim.stop(stop, timeout_s=60)
    assert status == 0, err
    capture, frames, _ = read_capture(earlier)
    assert capture.error is None and capture.info.tool == "aspod sim" and len(frames) >= 4
    with can.LogReader(str(tmp_path / "bus.asc")) as log:
        assert sum(1 for _ in log) > 100
    assert _temporaries(tmp_path) == []


@pytest.mark.pty
def test_a_rotated_can_log_stopped_by_sigint_is_its_parts_and_the_file_named(home, tmp_path):
    """`--can-rotate-mb`: the parts are put in place as they fill, the newest frames in the file named, every
    frame read back in order (docs/sessions.md)."""
    env, key, _ = home
    sim, url = _sim(env, key, "--speed", "max", "--can-log", str(tmp_path / "hal.log"), "--can-rotate-mb", "0.01")
    try:
        _ping(url, key)                  # by then the world has run well past 10 kB of frames (250 kB a second)
    finally:
        status, err = sim.stop(signal.SIGINT, timeout_s=60)
    assert status == 0, err
    assert "in parts of 0.01 MB: hal_#000.log, hal_#001.log, ... and the newest frames in it" in err
    parts = sorted(p for p in tmp_path.iterdir() if p.name.startswith("hal_#"))
    assert parts and [p.name for p in parts] == [f"hal_#{n:03}.log" for n in range(len(parts))]
    times = []
    for path in [*parts, tmp_path / "hal.log"]:
        assert path.stat().st_size <= 10_000 + 200, path          # a candump line is under 200 bytes
        with can.LogReader(str(path)) as log:
            times += [msg.timestamp for msg in log]
    assert len(times) > 100 and times == sorted(times)
    assert _temporaries(tmp_path) == []


@pytest.mark.pty
def test_a_live_capture_killed_outright_leaves_the_destination_as_it_was_and_its_frames_in_the_temporary(home,
                                                                                                       tmp_path):
    env, key, _ = home
    earlier = tmp_path / "s.pcapng"
    CaptureWriter.create(earlier, SessionInfo(tool="earlier")).close()
    before = earlier.read_bytes()
    sim, url = _sim(env, key, "--record", str(earlier))
    try:
        _ping(url, key)
    finally:
        status, _ = sim.stop(signal.SIGKILL, timeout_s=60)
    assert status == -signal.SIGKILL
    assert earlier.read_bytes() == before
    (left,) = _temporaries(tmp_path)
    assert left.name.startswith(".s.pcapng.") and left.name.endswith(".part.pcapng")
    capture, frames, _ = read_capture(left)                  # readable up to its last frame
    assert capture.info.tool == "aspod sim" and len(frames) >= 4


@pytest.mark.pty
def test_teleop_stopped_by_sigterm_puts_its_capture_in_place(home, tmp_path):
    env, key, _ = home
    sim, url = _sim(env, key)
    try:
        script = tmp_path / "s.aspod"
        script.write_text("status\nwatch 600\n")
        host = Child(["teleop", url, "--key-file", str(key), "--script", str(script), "--record",
                      str(tmp_path / "t.pcapng")], env=env)
        try:
            while "ok   Status" not in host.line(60.0):
                pass
        finally:
            status, err = host.stop(signal.SIGTERM, timeout_s=60)
        assert status == 128 + signal.SIGTERM, err
    finally:
        sim.stop()
    capture, frames, _ = read_capture(tmp_path / "t.pcapng")
    assert capture.error is None and capture.info.tool == "aspod teleop" and len(frames) >= 4
    assert _temporaries(tmp_path) == []


# ---- every output of every command, through the settings ----------------------------------------------------------

def parsed(*argv: str):
    return build_parser().parse_args(list(argv))


@pytest.fixture
def files(tmp_path, monkeypatch):
    """A run's inputs and a few existing files, the default parameter file in a private config folder."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    (tmp_path / "config" / "aspod").mkdir(parents=True)
    (tmp_path / "config" / "aspod" / "params.json").write_text("{}")
    for name, data in (("link.key", b""), ("s.aspod", b"status\n"), ("c.pcapng", CAPTURE_HEAD),
                       ("p.json", b"{}"), ("problem.json", b"{}"), ("finding.json", b"{}"), ("bench.py", b"")):
        (tmp_path / name).write_bytes(data)
    return tmp_path


CAPTURE_HEAD = b"\x0a\x0d\x0d\x0a" + bytes(28)

# (the command line, the option that names an output, the input it names) for every output of every command
EVERY_OUTPUT = [
    (["sim", "--key-file", "link.key"], "--record", "link.key", settings.sim_settings),
    (["sim", "--params", "p.json"], "--can-log", "p.json", settings.sim_settings),
    (["teleop", NOWHERE, "--script", "s.aspod"], "--record", "s.aspod", settings.teleop_settings),
    (["proxy", "--controller", "tcp:0", "--key-file", "link.key"], "--record", "link.key", settings.proxy_settings),
    (["demo"], "--record", "config/aspod/params.json", settings.demo_settings),
    (["bench", "s.aspod"], "--record", "s.aspod", settings.bench_settings),
    (["replay", "c.pcapng"], "--output", "c.pcapng", settings.replay_settings),
    (["log", "c.pcapng"], "--csv", "c.pcapng", settings.log_settings),
    (["log", "c.pcapng", "--key-file", "link.key"], "--plot", "link.key", settings.log_settings),
    (["tracker-day"], "--plot", "config/aspod/params.json", settings.day_plot),
    (["wireshark"], "--output", "config/aspod/params.json", settings.wireshark_output),
    (["schema", "--json"], "--output", "config/aspod/params.json", settings.schema_output),
    (["plan", "--problem", "problem.json"], "--plot", "problem.json", settings.plan_settings),
    (["campaign", "bench.py"], "--out", "bench.py", settings.campaign_settings),
    (["fuzz", "--replay", "finding.json", "--url", "/dev/null"], "--findings", "finding.json", settings.fuzz_settings),
    (["fuzz", "codec", "--key-file", "link.key"], "--corpus", "link.key", settings.fuzz_settings),
]


@pytest.mark.parametrize("argv, option, path, build", EVERY_OUTPUT, ids=[f"{a[0]} {o}" for a, o, _, _ in EVERY_OUTPUT])
def test_every_output_of_every_command_refuses_an_input_of_its_run(files, monkeypatch, argv, option, path, build):
    monkeypatch.chdir(files)
    if path.endswith("p.json") and option == "--can-log":           # (a --can-log needs a log's suffix)
        os.link("p.json", "p.log")
        path = "p.log"
    with pytest.raises(ValueError) as refusal:
        build(parsed(*argv, option, path))
    said = str(refusal.value)
    assert said.startswith(f"{option} ") and ("an input of this run" in said or "not a folder" in said
                                              or "cannot be made" in said), said
    assert (files / "link.key").read_bytes() == b"" and (files / "s.aspod").read_bytes() == b"status\n"


def test_an_output_named_twice_is_refused(files, monkeypatch):
    monkeypatch.chdir(files)
    for argv, said in ((["sim", "--record", "x.log", "--can-log", "x.log"], "--can-log x.log: --record writes there"),
                       (["log", "c.pcapng", "--csv", "x.png", "--plot", "x.png"], "--csv x.png: --plot writes there"),
                       (["--log-file", "x.pcapng", "bench", "s.aspod", "--record", "x.pcapng"],
                        "--record x.pcapng: --log-file writes there")):
        args = parsed(*argv)
        build = {"sim": settings.sim_settings, "log": settings.log_settings, "bench": settings.bench_settings}
        with pytest.raises(ValueError, match=said):
            build[args.command](args)


def test_what_each_output_counts_as_its_own_kind(tmp_path):
    """An existing file that begins as the output would is written over; an empty one too; anything else only with
    --force."""
    from host_tools.outputs import LOG_FILE, PNG
    from host_tools.sessions.export import CSV
    from host_tools.sessions.wireshark import DISSECTOR, generate_dissector
    from host_tools.worlds.can_log import KINDS
    theirs = {CAPTURE: CAPTURE_HEAD, PNG: b"\x89PNG\r\n\x1a\n....", CSV: b"time_s,link,direction,class,seq,message\n",
              DISSECTOR: generate_dissector().encode()[:200], LOG_FILE: b"2026-03-20 06:50:00,123 INFO aspod sim: ...\n",
              KINDS[".asc"]: b"date Sat Nov 28 17:58:26.957 2026\n", KINDS[".blf"]: b"LOGG\x90\x00",
              KINDS[".csv"]: b"timestamp,arbitration_id,extended,remote,error,dlc,data\n",
              KINDS[".log"]: b"(1.500000) plant 00000123#0102 R\n", KINDS[".trc"]: b";$FILEVERSION=2.1\r\n",
              KINDS[".txt"]: b"Timestamp:        1.500000    ID: 00000123"}
    for n, (kind, head) in enumerate(theirs.items()):
        name = f"f{n}{kind.suffixes[0] if kind.suffixes else ''}"
        for data, fits in ((head, True), (b"", True), (b"a key, a script, notes", False)):
            (tmp_path / name).write_bytes(data)
            if fits:
                assert Claims([]).file(tmp_path / name, "--out", kind), kind.name
            else:
                with pytest.raises(ValueError, match=f"not {re.escape(kind.name)}"):
                    Claims([]).file(tmp_path / name, "--out", kind)
            assert Claims([], force=True).file(tmp_path / name, "--out", kind)
        assert not any(kind.fits(other) for other_kind, other in theirs.items() if other_kind is not kind)


def test_what_is_not_a_writable_file_is_refused_naming_why(tmp_path):
    (tmp_path / "folder").mkdir()
    os.mkfifo(tmp_path / "fifo")
    for path, said in ((tmp_path / "folder", "a folder, not a file"), (tmp_path / "fifo", "a FIFO"),
                       (Path("/dev/null"), "a character device, not a regular file"),
                       (tmp_path / "no" / "x.png", f"no folder {tmp_path / 'no'}"),
                       (tmp_path / "x.jpg", "name it *.png"), (Path(UNWRITABLE) / "x.png", "cannot be written")):
        with pytest.raises(ValueError, match=re.escape(said)):
            Claims([]).file(path, "--plot", PNG_KIND)
    if os.geteuid() != 0:                        # (root writes a read-only file all the same)
        (tmp_path / "ro.png").write_bytes(b"")
        (tmp_path / "ro.png").chmod(0o444)
        with pytest.raises(ValueError, match="read-only"):
            Claims([]).file(tmp_path / "ro.png", "--plot", PNG_KIND)


def test_a_folder_of_outputs_is_checked_and_not_made_until_the_work_starts(tmp_path):
    claims = Claims([("the key", tmp_path / "key")])
    (tmp_path / "key").write_text("k")
    assert claims.folder(tmp_path / "a" / "b", "--findings") == tmp_path / "a" / "b"
    assert not (tmp_path / "a").exists()
    for path, said in ((tmp_path / "key", "that is the key"), (tmp_path / "key" / "x", "cannot be made"),
                       (Path(UNWRITABLE) / "x", "cannot be made in /proc"), (Path(UNWRITABLE), "cannot write in it")):
        with pytest.raises(ValueError, match=said):
            Claims([("the key", tmp_path / "key")]).folder(path, "--out")
    assert (tmp_path / "key").read_text() == "k"


# ---- writing: whole or not at all ----------------------------------------------------------------------------------

PNG_KIND = Kind("a PNG image", begins(b"\x89PNG"), (".png",))


def test_an_output_is_renamed_into_place_whole_with_the_mode_a_file_gets(tmp_path):
    out = unclaimed(tmp_path / "new.png", PNG_KIND)
    with out.open() as f:
        f.write(b"\x89PNG one")
        assert not out.path.exists() and len(_temporaries(tmp_path)) == 1
    assert out.path.read_bytes() == b"\x89PNG one" and _temporaries(tmp_path) == []
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(out.path.stat().st_mode) == 0o666 & ~umask
    out.path.chmod(0o640)
    out.write_bytes(b"\x89PNG two")                 # over an existing file: its mode stays
    assert out.path.read_bytes() == b"\x89PNG two" and stat.S_IMODE(out.path.stat().st_mode) == 0o640


def test_a_symbolic_link_as_output_writes_the_file_it_points_to(tmp_path):
    (tmp_path / "real.png").write_bytes(b"\x89PNG old")
    os.symlink("real.png", tmp_path / "link.png")
    Claims([]).file(tmp_path / "link.png", "--plot", PNG_KIND).write_bytes(b"\x89PNG new")
    assert (tmp_path / "link.png").is_symlink() and (tmp_path / "real.png").read_bytes() == b"\x89PNG new"


def test_an_output_whose_writing_fails_or_is_interrupted_leaves_the_destination_as_it_was(tmp_path):
    out = unclaimed(tmp_path / "x.csv", Kind("a table", begins(b"")))
    out.path.write_text("the earlier table\n")
    for error in (ValueError("a bug"), KeyboardInterrupt()):
        with pytest.raises(type(error)):
            with out.open(text=True) as f:
                f.write("half a tab")
                raise error
        kept(out.path, b"the earlier table\n")
    pending = out.open()                             # the destination turned into a folder meanwhile: cannot be put
    pending.file.write(b"rows")
    out.path.unlink()
    out.path.mkdir()
    with pytest.raises(OSError):
        pending.commit()
    assert _temporaries(tmp_path) == []
    pending = out.open()
    with pytest.raises(OSError):
        pending.commit(keep_on_error=True)           # a live capture's frames are kept where they are
    (left,) = _temporaries(tmp_path)
    assert left == pending.path


def test_a_capture_that_could_not_be_written_is_not_put_in_place_and_its_frames_are_kept(tmp_path):
    destination = tmp_path / "s.pcapng"
    CaptureWriter.create(destination, SessionInfo(tool="earlier")).close()
    before = destination.read_bytes()
    pending = unclaimed(destination, CAPTURE).open()

    class Filling:                                   # a disk that fills when told
        def __init__(self, file):
            self.file, self.full = file, False

        def write(self, data):
            if self.full:
                raise OSError(28, "No space left on device")
            return self.file.write(data)

        def flush(self):
            self.file.flush()
    disk = Filling(pending.file)
    writer = CaptureWriter(disk, SessionInfo(tool="aspod proxy"), pending=pending)
    writer.write("link", Direction.TO_CONTROLLER, b"\x01\x02\x00", 1.0)
    disk.full = True
    with pytest.raises(OSError):
        writer.write("link", Direction.TO_CONTROLLER, b"\x05\x06\x00", 2.0)
    writer.close()
    assert destination.read_bytes() == before and writer.partial.exists()
    assert len(read_frames(writer.partial)) == 1


def test_a_bench_run_interrupted_leaves_its_capture_as_it_was(tmp_path):
    destination = tmp_path / "b.pcapng"
    CaptureWriter.create(destination, SessionInfo(tool="earlier")).close()
    before = destination.read_bytes()

    class Interrupting:
        def write(self, text):
            raise KeyboardInterrupt

        def flush(self):
            pass
    with pytest.raises(KeyboardInterrupt):
        run_script_bench(WorldSettings(), ["status", "status"], out=Interrupting(),
                         capture=Output(destination, "--record", CAPTURE))
    kept(destination, before)
