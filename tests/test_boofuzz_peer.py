"""bench/boofuzz_peer.py, the peer of `aspod fuzz` in `python -m bench --only fuzz`, still opens a session with the
simulator (issue 35: after issue 34's Hello cookies it sent the old Hello and never had an answer)."""
from __future__ import annotations

import pytest

pytest.importorskip("boofuzz", reason="the bench extra: pip install -e '.[bench]'")

from bench.boofuzz_peer import run_boofuzz      # noqa: E402  (boofuzz first)

pytestmark = pytest.mark.pty


def test_boofuzz_opens_a_session_with_the_planted_simulator_and_runs_its_cases(tmp_path):
    result = run_boofuzz(tmp_path, 2.0, planted=True)
    assert result.cases > 0
    assert not result.found, result.found_case       # BoxDial's case is thousands in: the target lives
    assert any("health check" in note for note in result.notes)
