"""docs/vectors/ (issue 37): the committed vectors are what the link makes now, and an implementation written
from the documents alone (docs/vectors/check.py, Python's standard library in `python -I`) recomputes every byte
of them."""
from __future__ import annotations

import ast
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools.sessions import vectors
from protocol.reasons import Reason
from protocol.schema import MsgClass
from tests.aspod_cli import aspod

FOLDER = vectors.FOLDER
CHECK = FOLDER / "check.py"
# every reason a link sends in a Nak (protocol/link.py and controller_link.py: `_send_nak` through `_refuse`,
# `_auth_error`, `_frame_error`), and OUT_OF_RANGE, which comes as a command's Result
REFUSALS = {Reason.UNSUPPORTED_VERSION, Reason.UNSUPPORTED_FLAGS, Reason.BAD_LENGTH, Reason.UNAUTHENTICATED,
            Reason.BAD_MAC, Reason.NO_SESSION, Reason.UNKNOWN_MESSAGE, Reason.WRONG_DIRECTION, Reason.SEQUENCE_GAP,
            Reason.REPLAY, Reason.SESSION_CLOSED, Reason.OUT_OF_RANGE}


@pytest.fixture(scope="module")
def built() -> dict[str, bytes]:
    return vectors.build()


def check(folder: Path) -> subprocess.CompletedProcess:
    """check.py in an isolated interpreter (no site directory of the user, no PYTHONPATH, not the project's
    folder on sys.path), run from outside the project."""
    return subprocess.run([sys.executable, "-I", str(folder / "check.py"), str(folder)], cwd=folder.parent,
                          capture_output=True, text=True, timeout=120)


def test_the_committed_vectors_are_what_the_generator_writes_now(built):
    for name, data in built.items():
        assert (FOLDER / name).read_bytes() == data, \
            f"docs/vectors/{name} is stale: run `python -m host_tools.sessions.vectors` (make docs)"
    assert vectors.build() == built          # the same bytes every time: nothing random, no clock read


def test_an_implementation_from_the_documents_alone_gets_every_byte(tmp_path):
    done = check(FOLDER)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.startswith("ok: 6 derivations")


def test_the_independent_check_imports_only_the_standard_library():
    imported = set()
    for node in ast.walk(ast.parse(CHECK.read_text())):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            imported.add(node.module.split(".")[0])
    assert imported and imported <= set(sys.stdlib_module_names) | {"__future__"}, imported


@pytest.mark.parametrize("damage", ["tag", "crc", "cobs", "derived key", "nak tag", "capture"])
def test_the_independent_check_finds_a_wrong_byte(tmp_path, damage):
    folder = tmp_path / "vectors"
    shutil.copytree(FOLDER, folder)

    def edit(name: str, change) -> None:
        doc = json.loads((folder / name).read_text())
        change(doc)
        (folder / name).write_text(json.dumps(doc))

    def flip(text: str, at: int) -> str:
        return text[:at] + ("0" if text[at] != "0" else "1") + text[at + 1:]

    if damage == "tag":
        edit("frames.json", lambda d: d["frames"][0].update(tag_hex=flip(d["frames"][0]["tag_hex"], 3)))
    elif damage == "crc":
        edit("frames.json", lambda d: d["frames"][1].update(crc32=flip(d["frames"][1]["crc32"], 0)))
    elif damage == "cobs":
        edit("cobs.json", lambda d: d["cases"][3].update(cobs_hex="01" + d["cases"][3]["cobs_hex"]))
    elif damage == "derived key":
        edit("handshake.json", lambda d: d["derivations"][3].update(
            result_hex=flip(d["derivations"][3]["result_hex"], 10)))
    elif damage == "nak tag":
        def nak(d):
            fields = d["refusals"][4]["answer"]["message"]["fields"]
            fields[-1]["value"] = flip(fields[-1]["value"], 0)
        edit("refusals.json", nak)
    else:
        data = bytearray((folder / "session.pcapng").read_bytes())
        data[-40] ^= 0x01
        (folder / "session.pcapng").write_bytes(bytes(data))
    done = check(folder)
    assert done.returncode == 1 and "FAIL" in done.stdout, done.stdout + done.stderr


def test_every_refusal_of_the_link_has_its_vector():
    refusals = json.loads((FOLDER / "refusals.json").read_text())["refusals"]
    assert {Reason[r["reason"]] for r in refusals} == REFUSALS
    naks = [r for r in refusals if r["answer"]["message"]["name"] == "Nak"]
    assert len(naks) == len(refusals) - 1


def test_each_refusal_says_the_state_its_answer_follows_from():
    """`receiver` is the refusing end before the frame: its answer is signed with the next counter, and a NAK of a
    gap or an old duplicate names the number it expects."""
    for r in json.loads((FOLDER / "refusals.json").read_text())["refusals"]:
        receiver, answer = r["receiver"], r["answer"]
        assert answer["counter"] == receiver["last_counter_sent"] + 1, r["how"]
        fields = {f["name"]: f["value"] for f in answer["message"]["fields"]}
        if r["reason"] in ("SEQUENCE_GAP", "REPLAY", "SESSION_CLOSED"):
            expected = receiver.get("expected_command_seq", receiver.get("expected_event_seq"))
            assert fields["expected_seq"] == expected, r["how"]


def test_every_message_class_has_a_frame_in_the_session():
    frames = json.loads((FOLDER / "frames.json").read_text())["frames"]
    seen = {(MsgClass(f["header"]["class"]).name, f["direction"]) for f in frames}
    assert {"LINK", "COMMAND", "URGENT", "TELEMETRY", "EVENT"} == {cls for cls, _ in seen}
    assert ("COMMAND", "controller -> host") in seen and ("URGENT", "controller -> host") in seen


def test_aspod_log_prints_the_committed_listing(tmp_path):
    folder = tmp_path / "vectors"
    folder.mkdir()
    for name in ("session.pcapng", "psk.key"):
        shutil.copy(FOLDER / name, folder / name)
    done = aspod("log", "session.pcapng", "--key-file", "psk.key", cwd=folder)
    assert done.returncode == 0, done.stderr
    assert done.stdout == (FOLDER / "session.txt").read_text()
