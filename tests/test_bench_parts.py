"""The campaign bench prints as it goes and ends in a bounded time (issue 35: it printed nothing in 15 minutes)."""
from __future__ import annotations

import os
import sys
from concurrent.futures import ThreadPoolExecutor

from bench import run_parts
from bench.bench_campaign import SHORT, _runs, feed
from host_tools.worlds.child import Child


def test_a_part_s_lines_are_printed_as_it_goes_and_a_failure_half_way_keeps_them(capsys):
    seen_while_running = []

    def long_part(folder, quick):
        yield "first row"
        seen_while_running.append(capsys.readouterr().out)     # printed before the part goes on
        raise RuntimeError("the engine went away")

    def next_part(folder, quick):
        return ["next part's row"]

    result = run_parts("title", (long_part, next_part), True, "aspod-test-parts-")
    assert seen_while_running == ["title\nfirst row\n"]
    assert result.lines == ["first row", "long_part: could not run: RuntimeError: the engine went away",
                            "next part's row"]
    assert result.error == "long_part: RuntimeError: the engine went away"


def test_feed_gives_no_run_once_its_budget_is_spent(tmp_path):
    bench, runs = _runs(SHORT, 6, tmp_path)
    with ThreadPoolExecutor(1) as one:
        spent = feed(one, bench, runs, 2, budget_s=0.0)
        whole = feed(one, bench, runs, 2, budget_s=3600.0)
    assert [r.index for r in spent.results] == [runs[0].index, runs[1].index]     # those in flight finish
    assert [r.index for r in whole.results] == [run.index for run in runs]
    assert all(r.row["ok"] for r in whole.results) and whole.rows[runs[0].index] == spent.rows[runs[0].index]


def test_a_benchmark_s_line_reaches_a_pipe_as_it_is_printed_not_when_the_run_ends():
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}     # as `make bench | tee` has it
    code = ("from bench.__main__ import show_lines_as_printed; show_lines_as_printed(); print('first row'); "
            "import time; time.sleep(600)")
    child = Child(["-c", code], command=[sys.executable], env=env)
    try:
        assert child.line(timeout_s=10.0) == "first row"       # of its own time: it sleeps once it has printed
    finally:
        child.stop()
