"""The lock-step world gives, for a seed, the very bytes it gave before its tick path was made faster.

`tests/data/lockstep_reference.json` holds what the world with the tick path of commit 2d3728d (the
tick path before it was made faster: packed CAN frames between the nodes, the arm plant as its
per-concept classes) sent the host in a fixed session, hashed per simulated second, and the plant's state at
the end, written exactly (`float.hex`). The session: connect, telemetry at 10 Hz, enable, home
all axes (the home and limit switches, the gripper's stall), then the lock-step bench's moving
world (bench/bench_lockstep.py) for three segments: every joint jogged, the gripper closed and
opened, the tracker's control box in manual with its dials and direction switch turned.

A faster tick path must compute the same thing, to the bit: a change that moves one rounding
moves these bytes. Regenerate the file only for a change meant to alter what is simulated, and
say so in its commit. It was regenerated once since 2d3728d, with the tick path unchanged, for
issue 34's handshake (the cookie's round trip moves every command 14 ms later; the controller's
identity and cookie secret come from the seeded nonces before the session's; a new schema hash):

    python -m tests.test_same_bytes_as_before > tests/data/lockstep_reference.json
"""
from __future__ import annotations

import hashlib
import json
import sys
from datetime import datetime
from pathlib import Path
from typing import Callable

from hil_sim.sun import MST
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench, World
from protocol.messages import MESSAGES as M
from protocol.states import Axis, GripAction, Switch, SwitchPosition, TrackerAxis

REFERENCE = Path(__file__).resolve().parent / "data" / "lockstep_reference.json"
SEED = 7
SUN_START = datetime(2026, 6, 21, 10, 0, tzinfo=MST)      # the tracker's photocells in the sun
SEGMENT_S = 2.5
SEGMENTS = 3
JOG_DPS = {Axis.J1: 1.0, Axis.J2: 2.0, Axis.J3: 2.5, Axis.J4: 3.0, Axis.MOUNT: 1.5}


def run_session(direct_values: bool = True, watch: Callable[[World], None] = lambda world: None,
                fast_loop: bool = True) -> dict:
    """The session of the module docstring: bytes to the host per simulated second, the plant at the end.

    `direct_values` and `fast_loop` as `World` takes them; `watch(world)` is shown the world before the session
    starts (tests/test_direct_values.py runs the session both ways and records what the nodes receive)."""
    received: list[tuple[float, bytes]] = []
    bench: LockstepBench

    def tap(data: bytes) -> bytes:
        received.append((bench.clock.now(), data))
        return data

    bench = LockstepBench(seed=SEED, to_host=tap, plant=PlantSettings(start=SUN_START), direct_values=direct_values,
                          fast_loop=fast_loop)
    watch(bench.world)
    try:
        assert bench.connect()
        both = int(TrackerAxis.BOTH)
        for msg in (M["SetTelemetryRate"](10), M["Enable"](), M["BoxDial"](0.0, both),
                    M["BoxSwitch"](int(Switch.MODE), int(SwitchPosition.MANUAL), both),
                    M["BoxSwitch"](int(Switch.DIRECTION), int(SwitchPosition.CW), both),
                    M["BoxSwitch"](int(Switch.MAIN), int(SwitchPosition.ON), both),
                    M["BoxSwitch"](int(Switch.SPEED), int(SwitchPosition.ON), both), M["BoxDial"](50.0, both)):
            assert bench.call(msg).ok, msg
        home = bench.call(M["Home"](int(Axis.ALL)))
        assert home.ok
        started = {int(a): getattr(home.reply, f"{a.name.lower()}_motion_id") for a in Axis if a is not Axis.ALL}

        def homed() -> bool:
            ended = {(e.axis, e.motion_id) for e in bench.events if e.spec.name == "MotionDone"}
            return all((axis, motion) in ended for axis, motion in started.items())
        assert bench.wait_until(homed, 60.0), "homing did not end"
        sign = 1
        for _ in range(SEGMENTS):
            now = bench.clock.now()
            for axis, dps in JOG_DPS.items():
                bench.host.submit(M["Jog"](int(axis), sign * dps), now)
            bench.host.submit(M["Grip"](int(GripAction.CLOSE if sign > 0 else GripAction.OPEN)), now)
            direction = SwitchPosition.CW if sign > 0 else SwitchPosition.CCW
            for msg in (M["BoxDial"](0.0, both), M["BoxSwitch"](int(Switch.DIRECTION), int(direction), both),
                        M["BoxDial"](50.0, both)):
                bench.host.submit(msg, now)
            sign = -sign
            bench.run_for(SEGMENT_S)
        per_second: dict[int, hashlib._Hash] = {}
        for when, data in received:
            per_second.setdefault(int(when), hashlib.sha256()).update(data)
        plant = bench.world.plant
        return {
            "seed": SEED,
            "simulated_s": round(bench.clock.now(), 6),
            "bytes_to_host": sum(len(d) for _, d in received),
            "sha256_per_second": {str(s): h.hexdigest() for s, h in sorted(per_second.items())},
            "plant_end": {
                "encoder_counts": list(plant.encoder_counts),
                "currents_a": [float(i).hex() for i in plant.currents_a],
                "supply_v": float(plant.supply_v).hex(),
                "temp_c": float(plant.temp_c).hex(),
                "tracker_angle_deg": [float(a).hex() for a in plant.tracker.angle_deg],
            },
        }
    finally:
        bench.close()


def test_the_world_sends_the_host_the_same_bytes_as_before_and_ends_in_the_same_state():
    reference = json.loads(REFERENCE.read_text())
    got = run_session()
    assert got["simulated_s"] == reference["simulated_s"] and got["bytes_to_host"] == reference["bytes_to_host"]
    for second, digest in reference["sha256_per_second"].items():
        assert got["sha256_per_second"].get(second) == digest, f"the bytes to the host differ from second {second} on"
    assert got["sha256_per_second"] == reference["sha256_per_second"]
    assert got["plant_end"] == reference["plant_end"]


if __name__ == "__main__":
    result = run_session()
    json.dump({"made_by": "python -m tests.test_same_bytes_as_before", **result}, sys.stdout, indent=1)
    print()
