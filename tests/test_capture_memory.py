"""A capture is read as a stream: `aspod log`, with its counts and its plot, and `aspod replay` hold a bounded window
of it whatever the file's size, and a block larger than a reader holds is said with its offset, never read whole.
Memory is measured in a child process (its own peak resident set), never timed."""
from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest

from bench.bench_sessions import dense_telemetry_capture, lockstep_session, repeated_capture, run_measured
from host_tools.sessions.pcapng import EPB, EPB_FLAGS, IDB, INBOUND, MAX_BLOCK, MAX_KEPT
from tests.captures import read_frames
from tests.test_session_capture import record_session

MIB = 1 << 20
# What a bounded window may cost beyond the same command on a small capture: allocator noise. Before captures were
# streamed, `aspod log` on 16 MiB took 230 MB more than on a small one (20 times the file).
ALLOWED_GROWTH_KIB = 16 * 1024


def run_child(*args: str) -> tuple[int, str, str, int]:
    """(exit status, stdout, stderr, peak resident set in KiB) of `aspod ARGS` in a child process (VmHWM, the high-water
    mark of its memory since its exec)."""
    status, out, err, peak_kib, _ = run_measured(list(args), keep_stdout=True)
    return status, out, err, peak_kib


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("memory") / "session.pcapng"
    record_session(path, seconds=2.0)
    return path


@pytest.mark.parametrize("options", [(), ("--stats",), ("--plot", "PNG")], ids=["listing", "stats", "plot"])
def test_aspod_log_holds_a_bounded_window_whatever_the_captures_size(session, tmp_path, options):
    small = repeated_capture(session, tmp_path / "small.pcapng", 256 * 1024)
    big = repeated_capture(session, tmp_path / "big.pcapng", 8 * MIB)
    peaks = []
    for capture in (small, big):
        args = [a.replace("PNG", str(tmp_path / f"{capture.stem}.png")) for a in options]
        status, out, err, peak = run_child("log", str(capture), *args)
        assert status == 0, err[-2000:]
        peaks.append(peak)
    if options:
        assert "round trip COMMAND" in out or "plot written" in out
    else:
        frames = int(re.search(r"^# (\d+) frames", out, re.M).group(1))
        assert frames > 50_000 and out.count("\n") > frames
    assert peaks[1] - peaks[0] < ALLOWED_GROWTH_KIB, f"peak resident set {peaks} KiB: small, 8 MiB"


def _huge_block(f, kind: int, body_head: bytes, size: int, tail: bytes = b"") -> int:
    """A block of `size` bytes written sparse (its middle a hole: nothing stored, nothing read); its offset."""
    at = f.tell()
    f.write(struct.pack("<II", kind, size) + body_head)
    f.seek(at + size - 4 - len(tail))
    f.write(tail + struct.pack("<I", size))
    return at


def test_a_block_larger_than_a_reader_holds_is_said_with_its_offset_and_never_read_whole(session, tmp_path):
    data = session.read_bytes()
    first = read_frames(session)[0].offset
    big = tmp_path / "huge_blocks.pcapng"
    captured = 300 * MIB
    with open(big, "wb") as f:
        f.write(data)
        options = struct.pack("<HHI", EPB_FLAGS, 4, INBOUND) + struct.pack("<HH", 0, 0)
        packet_at = _huge_block(f, EPB, struct.pack("<IIIII", 0, 0, 0, captured, captured),
                                28 + captured + len(options) + 4, options)
        _huge_block(f, 0x0BAD, b"", 200 * MIB)         # a block of a type no reader knows: skipped as ever
        f.write(data[first:])
    status, out, err, peak = run_child("log", str(big))
    assert status == 0, err[-2000:]
    size = 28 + captured + len(options) + 4
    assert (f"a block of {size} bytes at byte {packet_at}, more than the 1 MiB this reader holds at once: its "
            f"packet of {captured} bytes is kept cut to {MAX_KEPT}") in err
    assert re.search(rf"C>H -\s+{captured} B  BAD_FRAME: {captured} bytes between delimiters", out), out[-3000:]
    assert out.count("Pong(") == 2 * 5                # the frames after the two huge blocks are read too
    assert peak < 200 * 1024, f"peak resident set {peak} KiB for a file of {big.stat().st_size // MIB} MiB"


def test_an_interface_larger_than_a_reader_holds_breaks_the_capture_there(session, tmp_path):
    data = session.read_bytes()
    big = tmp_path / "huge_interface.pcapng"
    with open(big, "wb") as f:
        f.write(data)
        at = _huge_block(f, IDB, struct.pack("<HHI", 147, 0, 0), 2 * MAX_BLOCK)
    status, out, err, _ = run_child("log", str(big))
    assert status == 1
    assert (f"the capture breaks at byte {at}: a block of {2 * MAX_BLOCK} bytes at byte {at}, more than the 1 MiB "
            "this reader holds at once: an interface this large is not read") in err
    assert out.count("Pong(") == 5


def test_aspod_replay_holds_a_bounded_window_whatever_the_captures_size(tmp_path):
    """A replay reads the recording a few seconds ahead of its simulation and judges what is a few seconds behind
    it (`replay.LOOKAHEAD_S`, `JUDGE_S`): 2 MiB of dense telemetry (6 s) fill that window as 12 MiB (36 s) do.
    Before, the whole capture was decoded and kept, twice (recorded and replayed): 12 MiB took 133 MB more."""
    session = tmp_path / "session.pcapng"
    lockstep_session(session, 2)
    peaks = []
    for name, size in (("short", 2 * MIB), ("long", 12 * MIB)):
        capture = dense_telemetry_capture(session, tmp_path / f"{name}.pcapng", size)
        status, out, err, peak = run_child("replay", str(capture))
        assert status == 1 and "first divergence at" in out, out + err[-2000:]
        peaks.append(peak)
    assert peaks[1] - peaks[0] < ALLOWED_GROWTH_KIB, f"peak resident set {peaks} KiB: 2 MiB, 12 MiB"
