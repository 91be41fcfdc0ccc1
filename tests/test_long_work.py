"""Long work (issue 36): progress on a terminal only, and a campaign that keeps its rows through Ctrl-C and resumes.

Every run is a real `aspod` subprocess; a progress bar is looked for through a real pty (stderr a terminal) and
looked for in vain through a pipe. Waits are on the child's own progress (its files, its exit), bounded by its own
time (host_tools/worlds/child.py), never a sleep.
"""
from __future__ import annotations

import csv
import fcntl
import os
import signal
import struct
import subprocess
import sys
import termios
import threading
from pathlib import Path

from host_tools.worlds.child import Child, run

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
SCRIPT = "ping\nenable\nwait ${w}\nstatus\n"


def on_pty(args: list[str], cwd: Path, timeout_s: float = 120.0) -> tuple[int, bytes, bytes]:
    """`aspod ARGS` with stderr a terminal of 80x24 (a pty) and stdout a pipe: (exit status, stdout, the terminal's
    bytes)."""
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    child = Child(args, env=ENV, stderr=slave)
    os.close(slave)
    seen, out = bytearray(), bytearray()

    def read_terminal() -> None:
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:             # EIO: the child's end is closed
                return
            if not data:
                return
            seen.extend(data)

    def read_stdout() -> None:
        out.extend(child.proc.stdout.read())
    readers = [threading.Thread(target=read_terminal), threading.Thread(target=read_stdout)]
    for reader in readers:
        reader.start()
    try:
        status = child.wait_exit(timeout_s)
    finally:
        child.stop()
        for reader in readers:
            reader.join()
        os.close(master)
    return status, bytes(out), bytes(seen)


def through_pipe(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return run([*ASPOD, *args], cwd=cwd, env=ENV, timeout_s=120.0, text=True)


def test_bench_shows_its_progress_on_a_terminal_only_and_ends_it_cleanly(tmp_path, monkeypatch):
    script = tmp_path / "short.txt"
    script.write_text(SCRIPT.replace("${w}", "20"))
    monkeypatch.chdir(tmp_path)
    status, out, terminal = on_pty(["bench", str(script)], tmp_path)
    assert status == 0, terminal[-500:]
    text = terminal.decode(errors="replace")
    assert "bench:" in text and "/20 simulated s" in text and "<" in text      # done/to do, and the time left
    assert terminal.endswith(b"\r"), terminal[-200:]            # the bar taken off the line at the end
    assert text.rstrip("\r").split("\r")[-1].strip() == ""
    piped = through_pipe(["bench", str(script)], tmp_path)
    assert piped.returncode == 0
    assert piped.stderr == ""                                   # nothing of it in a pipe
    assert piped.stdout.encode() == out                         # stdout the same either way


def test_a_spinner_with_the_simulated_time_when_the_script_waits_for_motions(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    script = tmp_path / "moves.txt"
    script.write_text("enable\nhome all\nwait all 60\nstatus\n")
    status, out, terminal = on_pty(["bench", str(script)], tmp_path)
    assert status == 0, terminal[-500:]
    text = terminal.decode(errors="replace")
    assert "bench " in text and " simulated s [" in text and "%" not in text


def campaign_folder(tmp_path: Path) -> Path:
    (tmp_path / "short.txt").write_text(SCRIPT)
    return tmp_path


def test_a_campaign_refuses_columns_no_row_will_have_before_its_first_run(tmp_path):
    cwd = campaign_folder(tmp_path)
    done = through_pipe(["campaign", "short.txt", "--vary", "w=1,2", "--serial", "--out", "c", "--hist", "nope",
                         "--group-by", "bad", "--plot", "sim_s:w"], cwd)
    assert done.returncode == 2
    assert "--hist nope: no column 'nope'" in done.stderr and "--group-by bad: no column 'bad'" in done.stderr
    assert "the rows' columns: run, seed, w, outcome" in done.stderr and "sim_s:w" not in done.stderr
    assert not (cwd / "c").exists()                             # nothing run, nothing written


def journal_lines(path: Path) -> int:
    try:
        return path.read_text().count("\n")
    except FileNotFoundError:
        return 0


def test_ctrl_c_keeps_the_rows_done_and_resume_runs_only_the_rest(tmp_path, monkeypatch):
    cwd = campaign_folder(tmp_path)
    args = ["campaign", "short.txt", "--vary", "w=5,6,7,8", "--serial"]
    whole = through_pipe([*args, "--out", "whole"], cwd)
    assert whole.returncode == 0, whole.stderr
    monkeypatch.chdir(cwd)
    child = Child([*args, "--out", "part"], env=ENV)
    journal = cwd / "part" / "runs.jsonl"

    def first_row(wait_s: float) -> bool:
        if journal_lines(journal) >= 1:
            return True
        try:
            child.proc.wait(timeout=min(wait_s, 0.05))          # the child ending is progress too
        except subprocess.TimeoutExpired:
            pass
        return journal_lines(journal) >= 1
    assert child.wait_for(first_row, 60.0)
    child.proc.send_signal(signal.SIGINT)
    status = child.wait_exit(60.0)
    _, err = child.stop()
    kept = journal_lines(journal)
    assert status == 130 and 1 <= kept < 4, (status, kept, err)
    assert f"interrupted: {kept} of 4 runs done" in err and "aspod campaign --resume part" in err
    assert not (cwd / "part" / "rows.csv").exists()
    resumed = through_pipe(["campaign", "--resume", "part"], cwd)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resuming part: {kept} of 4 runs done, {4 - kept} to run" in resumed.stdout
    runs = [line.split('"run": ')[1].split(",")[0] for line in journal.read_text().splitlines()]
    assert sorted(runs) == ["0", "1", "2", "3"]                 # each run once: none run again
    assert (cwd / "part" / "rows.csv").read_bytes() == (cwd / "whole" / "rows.csv").read_bytes()
    with (cwd / "part" / "rows.csv").open() as f:
        assert [r["run"] for r in csv.DictReader(f)] == ["0", "1", "2", "3"]


def test_resume_refuses_a_bench_file_changed_since_the_campaign_began(tmp_path):
    cwd = campaign_folder(tmp_path)
    began = through_pipe(["campaign", "short.txt", "--vary", "w=5,6", "--serial", "--out", "c"], cwd)
    assert began.returncode == 0, began.stderr
    rows = (cwd / "c" / "rows.csv").read_bytes()
    journal = cwd / "c" / "runs.jsonl"
    journal.write_text(journal.read_text().splitlines(keepends=True)[0])     # as if stopped after the first run
    script = cwd / "short.txt"
    script.write_text(script.read_text() + "ping\n")
    refused = through_pipe(["campaign", "--resume", "c"], cwd)
    assert refused.returncode == 2, refused.stderr
    assert "the bench file has changed since the campaign began there" in refused.stderr
    assert journal.read_text().count("\n") == 1 and (cwd / "c" / "rows.csv").read_bytes() == rows   # nothing run


def test_resume_takes_no_other_option_and_needs_a_campaign(tmp_path):
    cwd = campaign_folder(tmp_path)
    (cwd / "empty").mkdir()
    assert "no campaign begun there" in through_pipe(["campaign", "--resume", "empty"], cwd).stderr
    refused = through_pipe(["campaign", "--resume", "empty", "--serial"], cwd)
    assert refused.returncode == 2 and "nothing else with it" in refused.stderr
