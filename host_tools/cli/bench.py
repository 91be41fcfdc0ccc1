"""`aspod bench SCRIPT`: a teleop script against a whole world on the simulated clock (`BenchClient` on a
`LockstepBench`): deterministic, as fast as the machine goes, with the plant's true state at the end.

    aspod bench benches/tracker_procedure.aspod --sun-start 2026-03-20T06:50-07:00
    aspod bench session.txt --json > result.json
    aspod bench session.txt --record session.pcapng && aspod replay session.pcapng
"""
from __future__ import annotations

import json
import logging
import sys

from timebase import RealClock

from host_tools.worlds.plant_state import plant_state
from host_tools.cli.settings import BenchSettings
from host_tools.client.bench import BenchClient
from host_tools.exit_codes import EXIT_USAGE
from host_tools.sessions.capture import CaptureWriter, SessionInfo
from host_tools.teleop.record import ScriptRecord
from host_tools.teleop.session import run_script
from host_tools.teleop.sim_words import state_lines
from host_tools.teleop.words import TeleopError, read_script
from host_tools.worlds.world import LockstepBench

log = logging.getLogger("aspod")


def run_bench(settings: BenchSettings) -> int:
    try:
        lines = read_script(settings.script, option="script")
    except (OSError, TeleopError) as exc:
        log.error(f"aspod bench: {exc}")
        return EXIT_USAGE
    bench = LockstepBench(seed=settings.seed, plant=settings.plant)
    if settings.record is not None:
        bench.record(CaptureWriter.create(settings.record, SessionInfo(clock="simulated", tool="aspod bench",
                                                                       seed=settings.seed,
                                                                       settings=bench.settings())))
    wall0 = RealClock.precise_now()
    try:
        client = BenchClient(bench)
        client.connect()
        record = ScriptRecord(echo=None if settings.json else sys.stdout)
        status, session = run_script(client, lines, sys.stdout, keep_going=settings.keep_going,
                                     wall_time=client.wall_time, record=record)
        state = plant_state(bench.world.plant, bench.plant_settings.tracker)
        if settings.json:
            wall = RealClock.precise_now() - wall0
            print(json.dumps(record.as_dict(session, status, script=str(settings.script), target="lockstep",
                                            seed=settings.seed, sim_time_s=bench.clock.now(), wall_time_s=wall,
                                            plant=state), indent=1))
        else:
            print(session.summary())
            print(f"plant after {bench.clock.now():.1f} simulated s:")
            print("\n".join("  " + line for line in state_lines(state)))
        return status
    finally:
        bench.close()
