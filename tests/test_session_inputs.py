"""Bad session captures given to `aspod log` and `aspod replay`: refused with the reason, never a traceback or a hang."""
from __future__ import annotations

import os

import pytest

from host_tools.cli.main import main
from host_tools.sessions.pcapng import MAX_CAPTURE_BYTES


@pytest.mark.parametrize("command", ["log", "replay"])
def test_a_fifo_is_refused_not_waited_on(tmp_path, capsys, command):
    fifo = tmp_path / "capture.pcapng"
    os.mkfifo(fifo)
    assert main([command, str(fifo)]) == 2
    assert "FIFO" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["log", "replay"])
def test_a_capture_larger_than_the_limit_is_refused_unread(tmp_path, capsys, command):
    big = tmp_path / "big.pcapng"
    with open(big, "wb") as f:
        f.truncate(MAX_CAPTURE_BYTES + 1)          # sparse: nothing is written
    assert main([command, str(big)]) == 2
    assert "larger than 256 MiB" in capsys.readouterr().err
