"""The lock-step bench's moving world in a process of its own, driven line by line (bench_lockstep).

    PYTHONPATH=<a tree of this project> python bench/world_child.py [SEED]

It builds `bench.bench_lockstep.WorldRow` from whatever tree PYTHONPATH names: this one, for
worlds in parallel processes, or the tree of the commit before the tick path was made faster
(`git archive`), so that the old code is measured in the same run as the new. So it uses only
what `WorldRow` had then: its constructor, `advance`, `check`, `close` and the plant's `arm.pos_rad`.

Protocol, one line each way: it prints `ready` once the world is connected and enabled; each
line `SECONDS` it reads runs the world that many simulated seconds and answers the wall seconds
that took; `end` (or end of input) answers a JSON object (`error`: the row's check, '' when it did
what it should; `pos_rad`: the arm's joint angles, exactly, as float.hex) and exits.
"""
from __future__ import annotations

import json
import sys


def main(argv: list[str]) -> int:
    from bench.bench_lockstep import WorldRow
    from timebase import RealClock

    row = WorldRow("world in a child process", moving=True, timed_tasks=False, seed=int(argv[0]) if argv else 0)
    try:
        print("ready", flush=True)
        for line in sys.stdin:
            line = line.strip()
            if line == "end":
                break
            start = RealClock.precise_now()
            row.advance(float(line))
            print(RealClock.precise_now() - start, flush=True)
        print(json.dumps({"error": row.check(),
                          "pos_rad": [float(x).hex() for x in row.bench.world.plant.arm.pos_rad]}), flush=True)
    finally:
        row.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
