"""A small ground tool on `HostClient` (host_tools/client/live.py), for the hostile controller to attack, and a copy
of it with a planted defect: the proof that `aspod fuzz --as-controller` finds a host that crashes on an event.

    python -m host_tools.fuzz.hostile_planted URL KEY_FILE SECONDS [crash|hang|starved]

It does what a user's tool does: connects, asks (Ping, GetStatus, ParamGet) in a loop, names the axis of each
MotionDone event it hears, and connects again when its session is lost, for SECONDS; then closes and exits 0.
Two copies have a planted defect, each on an event the declaration allows:
- `crash`: it names the axis from a table one short (the mount and `all` are missing): a MotionDone of either
  raises in its listener, in the client's pump thread. The process lives on: the traceback on its stderr is what
  the fuzzer sees;
- `hang`: it waits for ever on a lock it already holds when a TemperatureWarning says it is too hot
  (a listener that calls back into its own code under the lock): no traceback, no exit, only silence.

And one without a defect that a busy machine slows: `starved`, once in session, moves its threads to one CPU at
SCHED_IDLE, beside a busy loop of its own there (0.9 s busy, 0.1 s idle). Its link
falls silent for most of a second at a time, which a wall clock would take for a hang; it must not be reported.
"""
from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

from protocol import auth
from protocol.errors import LinkError
from protocol.link import LinkState
from protocol.messages import SCHEMA
from protocol.states import Axis, TempSide
from timebase import RealClock

from host_tools.client.live import HostClient

AXIS_NAMES = {int(axis): axis.name.lower() for axis in Axis}
PLANTED_NAMES = ("j1", "j2", "j3", "j4", "gripper")      # the `crash` defect: the mount (and `all`) missing
CALL_TIMEOUT_S = 10.0


def run(url: str, key_file: Path, seconds: float, planted: str = "") -> int:
    psk = auth.load_key(key_file, "KEY_FILE")
    clock = RealClock()
    names = PLANTED_NAMES if planted == "crash" else AXIS_NAMES
    heard: list[str] = []
    lock = threading.Lock()

    def warn(msg) -> None:
        with lock:
            heard.append(f"{msg.side} at {msg.temp_c:g} degC")

    def on_event(msg, now: float) -> None:
        if msg.spec.name == "MotionDone":
            heard.append(names[msg.axis])
        elif msg.spec.name == "TemperatureWarning" and msg.active:
            if planted == "hang" and msg.side == TempSide.HOT:
                with lock:
                    warn(msg)            # the defect: takes the lock it holds
            else:
                warn(msg)

    hog = None
    asks = (SCHEMA["Ping"].type(token=7), SCHEMA["GetStatus"].type(), SCHEMA["ParamGet"].type(name="toy_gain"))
    end = clock.now() + seconds
    while clock.now() < end:
        client = HostClient(url, psk)
        client.event_listeners.append(on_event)
        try:
            client.connect(5.0)
            if planted == "starved" and hog is None:
                hog = starve()
            while clock.now() < end and client.link.state is LinkState.UP and client.io_error is None:
                for msg in asks:
                    client.call(msg, CALL_TIMEOUT_S)
        except LinkError:
            pass                       # refused or unanswered: a new client tries again
        finally:
            client.close()
    if hog is not None:
        hog.kill()
        hog.wait()
    print(f"done: {len(heard)} motions heard")
    return 0


HOG = ("import time\nwhile True:\n    end = time.monotonic() + 0.9\n    while time.monotonic() < end:\n        pass\n"
       "    time.sleep(0.1)\n")


def starve() -> subprocess.Popen:
    """A busy loop started on one CPU, and this process's threads moved there at SCHED_IDLE (they run only when
    nothing else would: no privilege needed), as are the threads they start."""
    cpu = max(os.sched_getaffinity(0))
    hog = subprocess.Popen([sys.executable, "-c", HOG], preexec_fn=lambda: os.sched_setaffinity(0, {cpu}))
    for thread in os.listdir("/proc/self/task"):
        os.sched_setaffinity(int(thread), {cpu})
        os.sched_setscheduler(int(thread), os.SCHED_IDLE, os.sched_param(0))
    return hog


def main(argv: list[str]) -> int:
    if len(argv) not in (3, 4) or argv[3:] not in ([], ["crash"], ["hang"], ["starved"]):
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    return run(argv[0], Path(argv[1]), float(argv[2]), argv[3] if len(argv) == 4 else "")


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
