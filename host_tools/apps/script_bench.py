"""A teleop script run on a lock-step world as one bench run: its record, the plant's truth at the end, and the
controller's answer to each fault the world injected. `aspod bench` prints it; `aspod campaign` makes a row of it.

    run = run_script_bench(WorldSettings(seed=3, faults=(TimedFault("jam:j2", 5.0),)), lines)
    run.status, run.record["steps"], run.record["plant"], run.record["faults"]
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Optional, TextIO

from timebase import RealClock

from host_tools.apps.fault_reaction import reactions
from host_tools.client.bench import BenchClient
from host_tools.outputs import Output
from host_tools.progress import Progress
from host_tools.sessions.capture import CaptureWriter, SessionInfo
from host_tools.teleop.record import ScriptRecord
from host_tools.teleop.session import run_script
from host_tools.teleop.words import check_script
from host_tools.worlds.bench_world import WorldSettings, build_bench
from host_tools.worlds.plant_state import plant_state


@dataclass
class ScriptRun:
    status: int         # as `aspod teleop --script`: 0 ok, 1 a line failed, 2 the script does not parse
    record: dict        # what `aspod bench --json` prints
    summary: str        # the session's summary, as teleop prints it at the end


def script_sim_s(lines: list[str]) -> Optional[float]:
    """The simulated seconds a script takes, where its waits say it: the sum of its pauses (`wait SECONDS`) and
    watches; None if it waits for something whose time is not known beforehand (motions, the tracker's alignment)
    or does not parse. (Each command's round trip adds milliseconds.)"""
    steps, problems = check_script(lines)
    if problems or any(s.waits_for_motion or s.waits_for_alignment for s in steps):
        return None
    return sum(s.seconds for s in steps if s.word in ("wait", "watch") and s.seconds is not None)


def run_script_bench(world: WorldSettings, lines: list[str], *, keep_going: bool = False,
                     out: Optional[TextIO] = None, err: Optional[TextIO] = None,
                     capture: Optional[Output] = None, script: Optional[str] = None,
                     shown: Optional[Progress] = None) -> ScriptRun:
    """Run `lines` on a world built as `world` says. `out`: where each line's output goes as it runs (None:
    nowhere but the record); `err`: the script's problems (None: into the record's `problems`); `capture`:
    a session capture of the link, on the simulated clock, put in place when the run ends (a run that raises,
    Ctrl-C say, leaves it as it was); `shown` follows the world's simulated clock (host_tools/progress.py).
    ValueError if the world cannot be built."""
    bench = build_bench(world)
    if shown is not None:
        shown.follow(bench.clock.now)
    writer = None
    if capture is not None:
        writer = CaptureWriter.create(capture, SessionInfo(clock="simulated", tool="aspod bench", seed=world.seed,
                                                           settings=bench.settings()))
        bench.record(writer)
    wall0 = RealClock.precise_now()
    problems = io.StringIO() if err is None else err
    try:
        client = BenchClient(bench)
        client.connect()
        record = ScriptRecord(echo=out)
        status, session = run_script(client, lines, io.StringIO() if out is None else out, keep_going=keep_going,
                                     err=problems, wall_time=client.wall_time, record=record)
        sim_time_s, state = bench.clock.now(), plant_state(bench.world.plant, bench.plant_settings.tracker)
        faults = reactions(bench, client.events, world.faults)       # (the world runs a moment further)
        result = record.as_dict(session, status, script=script, target="lockstep", seed=world.seed,
                                sim_time_s=sim_time_s, wall_time_s=RealClock.precise_now() - wall0,
                                plant=state, faults=faults)
        if err is None:
            result["problems"] = problems.getvalue().splitlines()
        client.close()                  # the session ends as a host's does, in the capture too
        return ScriptRun(status, result, session.summary())
    except BaseException:
        if writer is not None:
            writer.discard()
        raise
    finally:
        bench.close()
