"""bench/bench_codec.py compares like with like whatever length TelemetryStatus's payload has (issue 35: it refused
the 57-byte payload, having assumed 48)."""
from __future__ import annotations

import pytest

from bench import bench_codec
from protocol.messages import SCHEMA

OURS = SCHEMA[bench_codec.OURS]


@pytest.fixture(scope="module")
def common():
    pytest.importorskip("pymavlink", reason="the bench extra: pip install -e '.[bench]'")
    return bench_codec._load_pymavlink()


def test_todays_payload_is_compared_with_a_mavlink_message_of_its_length(common):
    cls, exact = bench_codec.mav_peer(common, OURS.size)
    assert exact and cls.unpacker.size == OURS.size
    assert "char" not in cls.fieldtypes
    rows = [bench_codec._ours(50, authenticated=False), bench_codec._ours(50, authenticated=True),
            bench_codec._pymavlink(common, cls, 50, signed=False), bench_codec._pymavlink(common, cls, 50, signed=True)]
    bench_codec.measure(rows, 1)        # every run's output checked: encoded bytes, decoded messages
    assert all(r.payload_bytes == OURS.size for r in rows)
    assert all(r.encode_fps and r.decode_fps and r.both_fps for r in rows)
    assert rows[2].wire_bytes == 10 + OURS.size + 2     # no trailing zero byte cut from the MAVLink payload


def test_a_length_no_message_has_is_compared_per_payload_byte(common):
    sizes = {c.unpacker.size for c in common.mavlink_map.values() if "char" not in c.fieldtypes}
    missing = next(n for n in range(OURS.size, 256) if n not in sizes)
    cls, exact = bench_codec.mav_peer(common, missing)
    assert not exact
    assert abs(cls.unpacker.size - missing) == min(abs(s - missing) for s in sizes)

    result = bench_codec.CodecResult(100, 1, missing, cls.msgname, per_byte=True)
    for name, payload in (("ours, unauthenticated", missing), ("pymavlink", cls.unpacker.size)):
        row = bench_codec.Row(name, 0, payload, frames=100)
        row.best_s = {column: 1.0 for column in bench_codec.COLUMNS}     # the same frames a second on both sides
        result.rows.append(row)
    text = bench_codec.report(result)
    assert "ratio per payload byte" in text
    ratio = f"{missing / cls.unpacker.size:.2f}"
    line = next(line for line in text.splitlines() if line.strip().startswith("ours unauth / pymavlink"))
    assert line.split()[4:7] == [ratio] * 3


def test_our_messages_are_valid_and_non_zero():
    msgs = bench_codec._our_messages(20)
    for m in msgs:
        assert OURS.decode(OURS.encode(m)) == m
        assert all(m)       # every field of TelemetryStatus can be non-zero
    assert len(set(msgs)) == len(msgs)
