"""Every command the README and docs/*.md show runs as shown, so no example can drift (issue 36).

Which text is a command (`doc_commands`, the one parser):

- a fenced block tagged `sh` (or `bash`, `shell`, `console`) holds commands: each line that is not blank
  and not a comment is one, joined with the next while it ends in `\\`; a leading `$ ` prompt is dropped;
  ` # ...` to the end of the line is its comment, and comment lines right below a command (no blank line
  between) continue that comment. Blank lines split a block into paragraphs.
- no other text holds commands: a line of an untagged fenced block, or of an indented one, that looks like
  a command (`aspod WORD`, `.venv/bin/`, `make `, `pytest `, `python -m `, `PYTHONPATH=`, `$ `) fails the
  test, so that a command cannot hide from it (tag its block `sh`, or `text` for a synopsis). Blocks
  tagged anything else (`text`, `python`, ...) and inline code in prose are not commands.

How they run (`DocRun`): each doc in a copy of this checkout (its tracked files and the new ones, so
`examples/`, `benches/` and `protocol/hal.dbc` are where the doc says and what the commands write stays
in the copy; the packages' folders linked, not copied, so their compiled code is this checkout's), with its own HOME, `aspod` and `.venv/bin/aspod` being this checkout's CLI, and MPLBACKEND
Agg (no window opens). A doc's commands run in its order, each as `bash -c TEXT`:

- `aspod sim`, `proxy`, `plant` and `firmware` run until stopped: started, judged on their ready line,
  and stopped at the end of their paragraph by SIGINT to their process group, as Ctrl-C at a terminal
  (so `aspod sim --can-log hal.log && cantools decode ...` goes on to its second half);
- `aspod teleop URL` with neither `--script` nor a pipe is the interactive console: started with a
  pseudo-terminal as its stdin, judged on its `link up:` line, stopped with SIGTERM (exit 143);
- anything else runs to its end and must exit 0, or with the status its comment states (`# exit 1`).

Addresses: what a running command's comment shows after a ready word (`# ASPOD-LINK /dev/pts/5`,
`ASPOD-KEY /tmp/aspod-1000/sim-7.key`) stands, in the commands after it, for what it really printed
there. Fixed ports (`--tcp 5000`, `port=43113`) are replaced by free ones in the whole doc: a fixed
port may be taken by another program or a parallel test.

Skipped, by name, with the reason: `SKIP`. A command too long for the suite runs shortened only when
its doc shows the short form too (`SHORTER`, checked). A command shown twice in one doc runs once.
Every wait is on the child's progress (its ready line, its exit, each bounded by its own CPU time:
host_tools/worlds/child.py), never a sleep.
"""
from __future__ import annotations

import dataclasses
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import pytest

from host_tools.client.control import ControlClient
from host_tools.worlds.child import Child, ChildError, run

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PACKAGES = ("kernels", "timebase", "protocol", "firmware_py", "hil_sim", "host_tools")     # pyproject.toml's
SH_TAGS = {"sh", "bash", "shell", "console"}
RUN_S = 900.0        # a command's bound, of its own CPU time (and 20x that of wall time: child.py)
STOP_S = 30.0

# Shown but not run: each needs what a test cannot have, or takes far longer than the suite may.
SKIP = {
    "make test": "the whole suite, this test among it (`make test` runs it)",
    "aspod campaign benches/test_pick_and_place.py --seeds 1000 --draw payload_kg=0..1 "
    "--draw fault=none,jam:j2,open_circuit:j1,encoder_dropout:j3,supply_sag,stuck_brake:j2 "
    "--draw fault_at_s=1..60 --group-by fault --plot m.worst_error_mm:payload_kg --hist fault.safe_after_s":
        "1000 runs: 21 minutes measured (docs/campaigns.md); the same matrix on 3 seeds, shown above it, runs",
    "aspod campaign benches/campaigns/tracker_dial.txt --vary dial=5,10,20 "
    "--vary sun_start=2026-01-15T12:00-07:00..2026-12-15T12:00-07:00/12 "
    "--plot plant.tracker.off_sun_deg:sun_start --group-by dial":
        "36 runs of about 5 minutes each (one measured at 287 s): hours on 2 cores",
    "aspod fuzz --replay fuzz-findings/crash-blackbox-....json --target-cmd '...'":
        "a pattern: the finding's name holds a hash known only once a fuzz run has found it "
        "(tests/test_fuzz.py and tests/test_fuzz_hangs.py replay real findings)",
    "aspod fuzz --as-controller --replay fuzz-findings/crash-hostile-....json --host-cmd '...'":
        "a pattern: a hostile controller's finding and your host's command (tests/test_fuzz_hostile.py replays one)",
    "aspod fuzz --replay fuzz-findings/oracle-my.module_factory-....json my.module:factory":
        "a pattern: your own module and a finding of it (tests/test_fuzz.py replays one)",
    "wireshark s.pcapng": "Wireshark's window: needs a display and a human",
    "aspod fuzz --as-controller --time 60": "it serves until a host comes, and the next line is that host (teleop, "
                                            "its link and key those the fuzzer printed): tests/test_fuzz_hostile.py "
                                            "points a host the test starts at it",
    "aspod teleop /dev/pts/7 --key-file /run/user/.../sim-123.key": "the host of the line above, at what it printed",
    "aspod fuzz --as-controller --serve tcp:5555 --key-file link.key --probe 'curl -fs localhost:8080/health'":
        "a ground tool of your own, its key, and its health endpoint on port 8080 (tests/test_fuzz_hostile.py runs "
        "a probe against a host the test starts)",
    "python -m can.viewer -i udp_multicast -c 239.74.163.2": "a curses viewer: needs a terminal and a human to quit it",
    "candump vcan0 | .venv/bin/python -m cantools decode protocol/hal.dbc":
        "needs a SocketCAN interface (vcan0: root to create it) and can-utils' candump",
}

# Too long for the suite as shown; run with options that the same doc shows on another command.
SHORTER = {
    ".venv/bin/aspod tracker-day --mode relay --dial 3 --json": "--from 11:00 --to 13:00",
    "aspod fuzz --as-controller --host-cmd 'aspod teleop {url} --key-file {key} --script examples/ground_check.txt' "
    "--time 60": "--time 10",
    "aspod fuzz --as-controller --host-cmd 'aspod teleop {url} --key-file {key} --script examples/ground_check.txt "
    "--keep-going' --time 60": "--time 10",
    ".venv/bin/aspod tracker-day --mode relay --dial 100 --plot hunt.png": "--from 11:00 --to 13:00",
    ".venv/bin/aspod tracker-day --mode feedforward --dial 100 --json": "--from 11:00 --to 13:00",
}

# A command whose tool may refuse, by name, what a busy machine made: replay refuses a recording whose world stalled
# more than 100 ms between two reports (README, "Not built yet"; docs/sessions.md), and the doc records one here.
# That refusal, exit 2 with these words, is the tool judging its input rightly, not the doc going wrong.
REFUSED_ON_A_BUSY_MACHINE = {command: "the recording's world stalled" for command in (
    "aspod replay run.pcapng", "aspod replay sim.pcapng",           # (sim.pcapng: a clean clone's CI, 2026-11-29)
    "aspod replay sim.pcapng --param j1_acc_dps2=1.5", "aspod replay sim.pcapng --json --output replayed.pcapng")}

SERVERS = {"sim": "ASPOD-LINK ", "proxy": "ASPOD-LINK ", "firmware": "ASPOD-LINK ", "plant": "ASPOD-PLANT ready"}
READY_LAST = {"sim": "ASPOD-CONTROL", "firmware": "ASPOD-KEY"}       # the last of its ready lines
LOOKS_LIKE_A_COMMAND = re.compile(r"^\s*(\$ |aspod [a-z-]+(?![a-z:-])|\.venv/bin/|make |pytest |python -m |PYTHONPATH=)")
OUTPUT_OPTIONS = {">", "-o", "--output", "--record", "--can-log", "--csv", "--plot", "--log-file", "--out"}
PATHLIKE = re.compile(r"^[\w.-]+(/[\w.-]+)*\.(txt|aspod|json|py|dbc|pcapng|key|log|blf|lua|csv|png|md)$"
                      r"|^(examples|benches|tests|protocol)/[\w./-]*$")


@dataclass
class Command:
    doc: str                    # relative to the checkout
    line: int                   # its first line in the doc
    text: str                   # as shown, lines joined, no prompt, no comment
    comment: str = ""
    block: int = 0
    paragraph: int = 0
    run: str = ""               # as it runs (DocRun.ports)


def split_comment(line: str) -> tuple[str, str]:
    """`text # comment` -> (text, comment): a `#` that starts a word outside quotes, as the shell reads it."""
    quote = None
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip(), line[i + 1:].strip()
    return line.rstrip(), ""


def doc_commands(path: Path) -> tuple[list[Command], list[str]]:
    """The commands `path` shows (the module's doc says which text counts), and the problems: lines that
    look like commands outside a `sh` block, each as `doc:line: text`."""
    rel = str(path.relative_to(ROOT))
    lines = path.read_text().split("\n")
    commands: list[Command] = []
    problems: list[str] = []
    tag: Optional[str] = None           # None: outside a fence; "" an untagged one
    block = paragraph = 0
    pending = ""                        # a command continued with a backslash
    start = 0
    last: Optional[Command] = None      # the command of the line above, for comment lines below it
    for number, raw in enumerate(lines, 1):
        stripped = raw.strip()
        if stripped.startswith("```"):
            if tag is None:
                tag, block, paragraph, last = stripped[3:].strip().lower(), block + 1, 0, None
            else:
                tag = None
            continue
        if tag is None:                 # prose, or an indented code block
            if raw.startswith("    ") and previous_blank_or_code(lines, number) and LOOKS_LIKE_A_COMMAND.match(raw):
                problems.append(f"{rel}:{number}: {stripped}  (an indented block: fence it as sh)")
            continue
        if tag not in SH_TAGS:
            if tag == "" and LOOKS_LIKE_A_COMMAND.match(raw):
                problems.append(f"{rel}:{number}: {stripped}  (an untagged block: tag it sh, or text if not a command)")
            continue
        if not stripped:
            paragraph += 1 if last is not None or pending else 0
            last = None
            continue
        if stripped.startswith("$ "):
            stripped = stripped[2:]
        text, comment = split_comment(stripped)
        if not text:
            if last is not None:
                last.comment = f"{last.comment} {comment}".strip()
            continue
        if not pending:
            start = number
        if text.endswith("\\"):
            pending += text[:-1].strip() + " "
            continue
        last = Command(rel, start, pending + text, comment, block, paragraph)
        pending = ""
        commands.append(last)
    return commands, problems


def previous_blank_or_code(lines: list[str], number: int) -> bool:
    """Line `number` (1-based) is in an indented code block: after a blank line or another indented line."""
    above = lines[number - 2] if number >= 2 else ""
    return not above.strip() or above.startswith("    ")


def words(text: str) -> list[str]:
    lexer = shlex.shlex(text, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    return list(lexer)


def first_program(text: str) -> tuple[str, list[str]]:
    """('aspod' or the program, the rest of the first pipeline's words)."""
    ws = words(text)
    cut = next((i for i, w in enumerate(ws) if w in {";", "&&", "||", "|", "&"}), len(ws))
    ws = ws[:cut]
    while ws and "=" in ws[0] and not ws[0].startswith("-"):
        ws = ws[1:]                     # VAR=value before the program
    if not ws:
        return "", []
    program = "aspod" if ws[0].endswith("aspod") else ws[0]
    return program, ws[1:]


def subcommand(args: list[str]) -> str:
    for i, word in enumerate(args):
        if not word.startswith("-"):
            if i and args[i - 1] in {"--log-file"}:
                continue
            return word
    return ""


def kind_of(text: str) -> str:
    """"server" (runs until stopped), "console" (the interactive teleop), or "run" (runs to its end)."""
    program, args = first_program(text)
    if program != "aspod" or "--help" in args:
        return "run"
    sub = subcommand(args)
    if sub in SERVERS:
        return "server"
    if sub == "teleop" and "--script" not in args and "<" not in args:
        return "console"
    return "run"


def expected_status(comment: str) -> int:
    found = re.search(r"\bexit (\d+)\b", comment)
    return int(found.group(1)) if found else 0


def named_files(text: str) -> list[tuple[str, bool]]:
    """The relative files a command names, each with whether it names it as an output (after `>` or an
    output option)."""
    ws = []
    for word in words(text):      # a command quoted inside one (--target-cmd, --host-cmd) names files too
        ws += words(word) if " " in word else [word]
    found = []
    for i, word in enumerate(ws):
        if word.startswith("lua_script:"):
            word = word.split(":", 1)[1]
        if re.fullmatch(r"[\w./-]+\.py:\w+", word):          # aspod fuzz FILE.py:FACTORY (your own target)
            word = word.rsplit(":", 1)[0]
        if PATHLIKE.match(word) and not word.startswith("fuzz-findings/"):
            found.append((word, i > 0 and (ws[i - 1] in OUTPUT_OPTIONS or ws[i - 2:i] == ["key", "new"])))
    return found


def all_commands() -> tuple[dict[str, list[Command]], list[str]]:
    by_doc, problems = {}, []
    for path in DOCS:
        commands, bad = doc_commands(path)
        problems += bad
        if commands:
            by_doc[str(path.relative_to(ROOT))] = commands
    return by_doc, problems


BY_DOC, PROBLEMS = all_commands()


# ---- what can be checked without running anything ------------------------------------------------------

def test_the_parser_reads_blocks_paragraphs_comments_and_continuations(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("prose `aspod sim` in prose\n\n```sh\n# a heading\naspod sim --pty   # ASPOD-LINK /dev/pts/5\n"
                    "                  # and more\naspod campaign x \\\n    --seeds 3   # exit 1\n\n"
                    "$ aspod log 'a # b'\n```\n\n```text\naspod campaign BENCH [--vary X]\n```\n\n"
                    "```\naspod bench x.txt\naspod sim: a line it prints\n```\n\n    aspod plan --json\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        commands, problems = doc_commands(page)
    finally:
        ROOT = saved
    assert [(c.line, c.text, c.comment, c.paragraph) for c in commands] == [
        (5, "aspod sim --pty", "ASPOD-LINK /dev/pts/5 and more", 0),
        (7, "aspod campaign x --seeds 3", "exit 1", 0),
        (10, "aspod log 'a # b'", "", 1)]
    assert [p.split(":")[1] for p in problems] == ["18", "22"]
    assert kind_of("aspod -q sim --pty --log-file sim.log") == "server"
    assert kind_of(".venv/bin/aspod teleop /dev/pts/N") == "console"
    assert kind_of("printf 'x' | .venv/bin/aspod teleop /dev/pts/N") == "run"
    assert kind_of("aspod sim --can-log hal.log && cantools decode protocol/hal.dbc < hal.log") == "server"
    assert expected_status("scripted; exit 0") == 0 and expected_status("3 runs; exit 1: a fault") == 1


def test_every_command_is_in_a_sh_block():
    """A command outside a `sh` block would not be run: tag it, or tag a synopsis `text`."""
    assert not PROBLEMS, "\n".join(PROBLEMS)


def test_the_docs_show_commands_and_the_skip_list_names_only_shown_ones():
    shown = {c.text for commands in BY_DOC.values() for c in commands}
    assert len(shown) > 80
    assert not set(SKIP) - shown, f"skipped but no longer shown: {sorted(set(SKIP) - shown)}"
    assert not set(REFUSED_ON_A_BUSY_MACHINE) - shown, sorted(set(REFUSED_ON_A_BUSY_MACHINE) - shown)
    assert not set(SHORTER) - shown, f"shortened but no longer shown: {sorted(set(SHORTER) - shown)}"


def test_a_shortened_command_uses_options_its_doc_shows():
    for text, extra in SHORTER.items():
        doc = next(d for d, commands in BY_DOC.items() if any(c.text == text for c in commands))
        assert any(extra in c.text and c.text not in SHORTER for c in BY_DOC[doc]), (
            f"{doc}: `{text}` is run with {extra!r}, which no other command there shows")


def test_every_file_the_docs_name_exists_or_an_earlier_command_writes_it():
    missing = []
    for doc, commands in BY_DOC.items():
        made: set[str] = set()
        for command in commands:
            if command.text in SKIP:
                continue
            for name, is_output in named_files(command.text):
                if is_output:
                    made.add(name)
                elif name not in made and not (ROOT / name).exists():
                    missing.append(f"{doc}:{command.line}: {name} (in `{command.text}`)")
    assert not missing, "named but neither in the checkout nor written before:\n" + "\n".join(missing)


def test_examples_holds_only_files_the_docs_use():
    named = {name for commands in BY_DOC.values() for c in commands for name, _ in named_files(c.text)}
    unused = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "examples").rglob("*"))
              if p.is_file() and "__pycache__" not in p.parts and str(p.relative_to(ROOT)) not in named]
    assert not unused, f"in examples/ but named by no doc command: {unused}"


# ---- running them -------------------------------------------------------------------------------------

def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Running:
    command: Command
    child: Child
    out: list[str] = field(default_factory=list)
    err: list[str] = field(default_factory=list)
    reader: Optional[threading.Thread] = None

    def drain(self) -> None:
        """Read its stdout and stderr from now on (a pipe nobody reads would stop a chatty child)."""
        self.child.follow_stderr(self.err.append)
        stdout = self.child.proc.stdout

        def read() -> None:
            try:
                for raw in iter(stdout.readline, b""):
                    self.out.append(raw.decode(errors="replace").rstrip("\n"))
            except (ValueError, OSError):
                pass
        self.reader = threading.Thread(target=read, daemon=True)
        self.reader.start()

    def said(self) -> str:
        if self.reader is not None:
            self.reader.join(5)
        return "\nstdout: " + "\n".join(self.out[-15:]) + "\nstderr: " + "\n".join((self.child.seen + self.err)[-15:])


def answers(path: Path, timeout_s: float) -> bool:
    """The control endpoint at `path` answers `info` within `timeout_s`."""
    try:
        with ControlClient(path, timeout_s) as control:
            control.request({"op": "info"}, timeout_s)
        return True
    except OSError:
        return False


class DocRun:
    """One doc's commands, in its order, in a copy of the checkout (the module's doc)."""

    def __init__(self, doc: str, base: Path) -> None:
        self.doc = doc
        self.dir = base / "checkout"
        self.home = base / "home"
        self.home.mkdir()
        runtime = base / "run"            # the simulators' keys and endpoints: this doc's alone
        runtime.mkdir(mode=0o700)
        listed = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-co", "--exclude-standard", "-z"],
                                check=True, capture_output=True, text=True).stdout.split("\0")
        for package in PACKAGES:          # the code itself, linked: a child started with `-m` finds it in its cwd
            (self.dir / package).parent.mkdir(parents=True, exist_ok=True)
            (self.dir / package).symlink_to(ROOT / package)
        for name in filter(None, listed):
            source = ROOT / name
            if source.is_file() and not source.is_symlink() and name.split("/", 1)[0] not in (*PACKAGES, ".venv"):
                (self.dir / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(source, self.dir / name)
        venv_bin = self.dir / ".venv" / "bin"
        venv_bin.mkdir(parents=True)
        (venv_bin / "aspod").write_text(f"#!{sys.executable}\nimport sys\nfrom host_tools.cli.main import main\n"
                                        "if __name__ == '__main__':\n    sys.exit(main())\n")   # as pip's script: a
        # Dask worker process started by spawn imports this file again, which must not run the command again
        (venv_bin / "python").write_text(f'#!/bin/sh\nexec {shlex.quote(sys.executable)} "$@"\n')
        for tool in venv_bin.iterdir():
            tool.chmod(0o755)
        (self.dir / ".venv" / ".installed").touch()     # `make demo`: installed already (the Makefile's stamp)
        env = {k: v for k, v in os.environ.items()
               if not k.startswith(("PYTEST_", "XDG_CONFIG", "XDG_STATE", "XDG_DATA", "XDG_CACHE"))}
        env.update(PATH=f"{venv_bin}:{Path(sys.executable).parent}:{env.get('PATH', '/usr/bin:/bin')}",
                   PYTHONPATH=str(ROOT), HOME=str(self.home), XDG_RUNTIME_DIR=str(runtime), MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
        self.env = env
        self.commands = [dataclasses.replace(c) for c in BY_DOC[doc]]     # .text as shown; .run with free ports
        self.bound: dict[str, str] = {}
        self.ran: list[str] = []
        self.skipped: list[str] = []

    def ports(self) -> None:
        """Each fixed port of the doc's commands (and their comments) replaced by a free one."""
        for c in self.commands:
            c.run = c.text
        found = {}
        for c in self.commands:
            for m in re.finditer(r"--tcp (\d+)\b", c.text):
                if m.group(1) != "0":
                    found[m.group(1)] = socket.SOCK_STREAM
            for m in re.finditer(r"\bport=(\d+)\b", c.text):
                found[m.group(1)] = socket.SOCK_DGRAM
        for old, kind in found.items():
            new = str(free_port(kind))
            pattern = re.compile(rf"(?<!\d){old}(?!\d)")
            for c in self.commands:
                c.run, c.comment = pattern.sub(new, c.run), pattern.sub(new, c.comment)

    def substitute(self, text: str) -> str:
        for shown in sorted(self.bound, key=len, reverse=True):
            text = re.sub(rf"(?<![\w/.-]){re.escape(shown)}(?![\w/.-])", self.bound[shown], text)
        return text

    def where(self, command: Command) -> str:
        return f"{command.doc}:{command.line}: `{command.text}`"

    def start(self, command: Command, text: str, stdin=subprocess.DEVNULL) -> Running:
        child = Child([text], command=("env", "-C", str(self.dir), "bash", "-c"), env=self.env, stdin=stdin,
                      new_session=True)
        return Running(command, child)

    def serve(self, command: Command, text: str) -> Running:
        """Started and ready: every ready line it prints out (a sim's control endpoint answering, as the tools
        that find a simulator by its address ask it), and what its comment shows of them bound."""
        running = self.start(command, text)
        _, args = first_program(text)
        sub = subcommand(args)
        last = READY_LAST.get(sub)
        if sub == "sim" and ("--no-control" in args or "--hal" in args):
            last = "ASPOD-KEY"          # no endpoint, or (separate processes) one it does not print
        printed: dict[str, str] = {}
        try:
            line = running.child.ready(SERVERS[sub])
            while True:
                word, _, value = line.partition(" ")
                printed[word] = value
                if last is None or word == last:
                    break
                line = running.child.line()
            if "ASPOD-CONTROL" in printed:
                path = Path(printed["ASPOD-CONTROL"])
                if not running.child.wait_for(lambda s: answers(path, s), STOP_S):
                    raise ChildError(f"its control endpoint {path} does not answer")
        except ChildError as exc:
            running.child.stop()
            pytest.fail(f"{self.where(command)}: not ready: {exc}")
        for word, shown in re.findall(r"(ASPOD-[A-Z]+) (\S+)", command.comment):
            shown = shown.rstrip(",;:")
            if "/" in shown or ":" in shown:        # an address or a path, not a word such as PATH
                assert word in printed, f"{self.where(command)}: its comment shows {word}, which it did not print"
                self.bound[shown] = printed[word]
        running.drain()
        return running

    def stop(self, running: Running) -> None:
        child = running.child
        try:
            os.killpg(child.pid, signal.SIGINT)              # Ctrl-C at its terminal
        except ProcessLookupError:
            pass
        try:
            status = child.wait_exit(STOP_S)
        except ChildError:
            status, _ = child.stop(signal.SIGTERM)
        child.stop()
        assert status in (0, 130), f"{self.where(running.command)}: stopped by Ctrl-C, exit {status}{running.said()}"

    def console(self, command: Command, text: str) -> None:
        master, slave = os.openpty()
        try:
            running = self.start(command, text, stdin=slave)
            try:
                running.child.ready("link up: ")
            except ChildError as exc:
                running.child.stop()
                pytest.fail(f"{self.where(command)}: the console did not come up: {exc}")
            running.drain()
            status, _ = running.child.stop(signal.SIGTERM)
            assert status == 143, f"{self.where(command)}: SIGTERM ended it with {status}{running.said()}"
        finally:
            os.close(slave)
            os.close(master)

    def once(self, command: Command, text: str) -> None:
        try:
            done = run(["bash", "-c", text], cwd=self.dir, env=self.env, stdin=subprocess.DEVNULL, text=True,
                       timeout_s=RUN_S)
        except subprocess.TimeoutExpired as exc:
            pytest.fail(f"{self.where(command)}: still running after {RUN_S:g} s of its own time: {exc.stderr}")
        want = expected_status(command.comment)
        said = REFUSED_ON_A_BUSY_MACHINE.get(command.text)
        if said is not None and done.returncode == 2 and said in (done.stderr or ""):
            print(f"{self.where(command)}: refused what a busy machine recorded: {done.stderr.strip()}")
            return
        assert done.returncode == want, (f"{self.where(command)}: exit {done.returncode}, not {want}\n"
                                         f"stdout: {(done.stdout or '')[-3000:]}\nstderr: {(done.stderr or '')[-3000:]}")

    def run_all(self) -> None:
        self.ports()
        running: list[Running] = []
        place = None
        try:
            for command in self.commands:
                if (command.block, command.paragraph) != place:
                    while running:
                        self.stop(running.pop())
                    place = (command.block, command.paragraph)
                if command.text in SKIP:
                    self.skipped.append(command.text)
                    continue
                text = self.substitute(command.run)
                if command.text in SHORTER:
                    text = f"{text} {SHORTER[command.text]}"
                kind = kind_of(text)
                if kind == "run" and command.text in self.ran:
                    continue            # shown again: it ran above (a server is started again: it is needed)
                if kind == "server":
                    running.append(self.serve(command, text))
                elif kind == "console":
                    self.console(command, text)
                else:
                    self.once(command, text)
                self.ran.append(command.text)
            while running:
                self.stop(running.pop())
        finally:
            for left in running:
                left.child.stop()


QUICK = {"docs/hal_bus.md", "docs/planning.md", "docs/fidelity.md"}


def doc_params():
    for doc in BY_DOC:
        marks = [pytest.mark.realtime] + ([] if doc in QUICK else [pytest.mark.long])
        yield pytest.param(doc, marks=marks, id=doc)


@pytest.mark.parametrize("doc", list(doc_params()))
def test_the_commands_of_a_doc_run_as_shown(doc, tmp_path):
    runner = DocRun(doc, tmp_path)
    runner.run_all()
    shown = [c.text for c in BY_DOC[doc]]
    assert set(runner.ran) | set(runner.skipped) == set(shown)
    print(f"{doc}: {len(runner.ran)} run, {len(runner.skipped)} skipped")


def test_the_readmes_python_example_runs_as_shown(tmp_path):
    """The front page's `python` block, as a script of its own (a new process, the checkout's packages)."""
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.M | re.S)
    assert len(blocks) == 1
    script = tmp_path / "example.py"
    script.write_text(blocks[0])
    done = run([sys.executable, str(script)], cwd=ROOT, text=True, timeout_s=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("Status(result=0, state=2,"), done.stdout
