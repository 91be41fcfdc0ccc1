"""What a bench talks to: a controller with its world, the same API whether it is simulated or real.

`LockstepTarget`: a whole world on the simulated clock (`LockstepBench`), deterministic for its seed, as
fast as the machine goes; the plant can be faulted and read. `LiveTarget`: a live controller over any
pyserial URL (an `aspod sim` on a pty or TCP port, or real hardware), in real time; an `aspod sim`'s plant
is faulted and read through its control endpoint (host_tools/worlds/control_server.py: given, or found
from the URL), and its time paused and stepped. Real hardware has no such endpoint: a bench that needs the
plant is skipped there (`CannotFault`, with the reason), never faked. Both reach the plant with the same
requests (host_tools/worlds/plant_control.py), so a fault does the same on either.

    target.call(msg) -> CommandHandle          one command, its one outcome
    target.wait_until(predicate, timeout_s)    in the target's time (simulated: runs the world; live: the controller's)
    target.now()                               the target's time (live: the controller's uptime, as it last said it)
    target.telemetry["TelemetryJoints"]        the latest of each telemetry message
    target.events                              every event, in order
    target.link_stats()                        the host link's counters
    target.run_script(text) -> dict            a teleop script, its record (host_tools/teleop/record.py)
    target.inject(fault, channel) / clear(...) plant faults by name (hil_sim/faults.py); CannotFault if not here
    target.act(name, *args)                    a plant action by name (host_tools/worlds/plant_actions.py)
    target.true_state() -> dict                the plant's truth, where there is one to read
    target.pause() / resume() / step(seconds)  a live simulator's time held, stepped, paced again
    target.measure(name, value, unit)          a figure of the bench, for its record
    target.variables                           the bench's variables (--aspod-var NAME=VALUE; a campaign's axes)
"""
from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

from protocol.host_link import CommandHandle
from protocol.link import LinkState
from protocol.messages import MESSAGES as M
from protocol.schema import Message
from protocol.states import ControllerState

from host_tools.apps.fault_reaction import reactions
from host_tools.worlds import plant_actions, plant_control
from host_tools.client.bench import BenchClient
from host_tools.client.control import open_control
from host_tools.client.live import HostClient
from host_tools.plugin.errors import CannotFault
from host_tools.teleop.record import ScriptRecord
from host_tools.teleop.session import run_script
from host_tools.worlds.bench_world import WorldSettings, build_bench


UNDO_WAIT_S = 10.0        # a live bench's end: how long the controller may refuse the reset of a fault it injected
SETTLED_MS = 300          # ... and how long (its own time) it must then stay IDLE


@dataclass
class Target:
    """A connected client (`BenchClient` or `HostClient`) and what the bench has seen through it."""
    client: Any
    kind: str
    variables: dict[str, str] = field(default_factory=dict)       # the bench's variables (--aspod-var)
    telemetry: dict[str, Message] = field(default_factory=dict)
    measurements: dict[str, dict] = field(default_factory=dict)    # name -> {"value", "unit"}: `measure`
    pausable = True       # (not a field) its time can be held, where there is a control endpoint

    def __post_init__(self) -> None:
        self.client.telemetry_listeners.append(lambda msg, now: self.telemetry.__setitem__(msg.spec.name, msg))
        self._injected: list[tuple[str, Optional[str]]] = []     # plant faults this bench injected, not cleared
        self._held = False                                        # this bench paused the simulator

    @property
    def events(self) -> list[Message]:
        return self.client.events

    def now(self) -> float:
        return self.client.clock.now()

    def call(self, msg: Message, timeout_s: float = 30.0) -> CommandHandle:
        return self.client.call(msg, timeout_s)

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        return self.client.wait_for(predicate, timeout_s)

    def measure(self, name: str, value: float, unit: str = "") -> None:
        """Keep a figure of this bench (the plugin puts it in the test's record and JUnit properties)."""
        self.measurements[name] = {"value": value, "unit": unit}

    def link_stats(self):
        return self.client.link.stats

    def run_script(self, text: str, keep_going: bool = False) -> dict:
        record = ScriptRecord()
        status, session = run_script(self.client, text.splitlines(), io.StringIO(), keep_going=keep_going,
                                     err=io.StringIO(), wall_time=self._wall_time(), record=record)
        return record.as_dict(session, status, target=self.kind)

    def _wall_time(self):
        from timebase import RealClock
        return RealClock.wall_time

    # ---- the plant, through a simulator's control endpoint (None: there is none) ----
    @property
    def control(self):
        return self.client.control

    @property
    def can_fault(self) -> bool:
        return self.control is not None

    @property
    def can_pause(self) -> bool:
        return self.pausable and self.control is not None

    def no_plant(self) -> str:
        """Why there is no plant to reach (`CannotFault`'s reason)."""
        return f"the {self.kind} target has no plant to fault from here"

    def sim(self, request: dict) -> dict:
        """One request of the control endpoint, its reply; ValueError with the reason if it was refused."""
        if self.control is None:
            raise CannotFault(self.no_plant())
        reply = self.control.request(request)
        if not reply["ok"]:
            raise ValueError(reply["error"])
        return reply

    def inject(self, fault: str, channel: Optional[str] = None) -> None:
        self.sim({"op": "fault", "name": fault, "channel": channel})
        self._injected.append((fault, channel))

    def clear(self, fault: str, channel: Optional[str] = None) -> None:
        self.sim({"op": "clear", "name": fault, "channel": channel})
        if (fault, channel) in self._injected:
            self._injected.remove((fault, channel))

    def act(self, name: str, *args) -> None:
        self.sim(plant_actions.control_request(name, *args))

    def true_state(self) -> dict:
        return self.sim({"op": "state"})["state"]

    def _held_request(self, request: dict) -> dict:
        if self.control is not None and not self.pausable:
            raise CannotFault(plant_control.NO_PAUSE)
        return self.sim(request)

    def pause(self) -> None:
        """Hold the simulator's time: the plant and the controller's loops stand still, the link stays up."""
        self._held_request({"op": "pause"})
        self._held = True

    def resume(self) -> None:
        self._held_request({"op": "resume"})
        self._held = False

    def step(self, seconds: float) -> float:
        """Run a held simulator `seconds` further (as fast as it goes); returns its time then."""
        return self._held_request({"op": "step", "seconds": seconds})["time_s"]

    def close(self) -> None:
        """Leave the simulator as the bench found it, then close the session (`HostClient.close`: the controller
        goes IDLE, no fault): its time resumed if the bench held it, the plant faults it injected cleared, and the
        controller's fault they latched reset, so that the next bench, or the next run, starts clean."""
        try:
            self._undo()
        finally:
            self.client.close()

    def _undo(self) -> None:
        if self.control is None or not (self._held or self._injected):
            return
        if self._held:
            self.resume()
        faulted = bool(self._injected)
        for fault, channel in list(self._injected):
            self.clear(fault, channel)
        if faulted and self.client.link.state is LinkState.UP:
            self._reset_when_settled()

    def _reset_when_settled(self) -> None:
        """Reset the controller, and again until it stays IDLE for `SETTLED_MS` of its own time: a fault's cause may
        take a moment to go (reset refused meanwhile), or raise one more fault as it goes (an encoder's counts
        jumping when they come back), which a reset made too soon would let stand."""
        deadline = self.now() + UNDO_WAIT_S
        while self.now() < deadline and self.client.link.state is LinkState.UP:
            if not self.call(M["Reset"]()).ok:
                self.wait_until(lambda: False, 0.1)
                continue
            since_ms = self.call(M["GetStatus"]()).reply.uptime_ms
            while self.now() < deadline:
                status = self.call(M["GetStatus"]()).reply
                if status is None or status.state != ControllerState.IDLE or status.faults:
                    break
                if status.uptime_ms - since_ms >= SETTLED_MS:
                    return
                self.wait_until(lambda: False, 0.05)

    def close_record(self) -> dict:
        """Close the target; what the test's record keeps of it."""
        self.close()
        return {"sim_time_s": self.now()}


class LockstepTarget(Target):
    """A whole world on the simulated clock, as `world` says (its faults injected at their times), connected."""

    pausable = False      # its time moves only while the bench waits

    def __init__(self, world: WorldSettings = WorldSettings(seed=1), variables: Optional[dict[str, str]] = None) -> None:
        self.world = world
        self.bench = build_bench(world)
        client = BenchClient(self.bench)
        super().__init__(client, "lockstep", dict(variables or {}))
        client.connect()
        # `--aspod-arms 2`: the second arm's controller, on its own link: a target of its own, without the plant's
        # control (the first arm's target has it, the object included in `true_state`)
        self.arm2: Optional[Target] = None
        if world.arms == 2:
            second = BenchClient(self.bench, arm=2)
            self.arm2 = Target(second, "lockstep arm 2", dict(variables or {}))
            second.connect()

    def close_record(self) -> dict:
        record = {"sim_time_s": self.now(), "seed": self.world.seed,
                  "faults": reactions(self.bench, self.events, self.world.faults)}
        self.close()
        return record

    def _wall_time(self):
        return self.client.wall_time

    def close(self) -> None:
        if self.arm2 is not None:
            self.arm2.close()
        self.bench.close()


CONTROLLER_SILENCE_S = 15.0   # a wait in the controller's time ends when nothing has told its time for this long (wall)


class LiveTarget(Target):
    """A live controller at `url` (pyserial URL or device; several links comma-separated), connected; with the
    simulator's control endpoint at `control_path`, or else the one found beside `url`, if any.

    Its time is the controller's, as its telemetry, its events and its Status say it (`uptime_ms`): a simulator on
    a busy machine slows its world down rather than fault, and a bench's bounds (a fault drill's reaction, a
    `wait_until`) are then waited for in that time, as on the lock-step world, never failed on the wall clock's.
    `now()` is as fresh as the telemetry rate (10 Hz by default: 0.1 s). A wait ends early, False, once nothing has
    told the controller's time for `CONTROLLER_SILENCE_S` of wall time (the link down, telemetry off and nothing
    happening).
    """

    def __init__(self, url: str, psk: bytes, baud: int = 115200, control_path: Optional[Path] = None,
                 variables: Optional[dict[str, str]] = None) -> None:
        control = open_control(url, control_path)
        try:
            client = HostClient(url, psk, baud=baud, control=control)
        except BaseException:
            if control is not None:
                control.close()
            raise
        super().__init__(client, f"live {url}", dict(variables or {}))
        self._uptime_ms: Optional[int] = None    # the controller's latest time
        self._told = 0                           # messages that told it
        client.telemetry_listeners.append(lambda msg, now: self._timed(msg))
        client.event_listeners.append(lambda msg, now: self._timed(msg))
        try:
            client.connect()
            status = client.call(M["GetStatus"]())
            if status.ok:
                self._timed(status.reply)
        except BaseException:
            client.close()
            raise

    def _timed(self, msg: Message) -> None:
        """A message that says the controller's time (telemetry, events, Status): the latest time said is kept (an
        event carried over from an earlier session says an earlier one)."""
        uptime_ms = getattr(msg, "uptime_ms", None)
        if uptime_ms is not None:
            self._uptime_ms = max(uptime_ms, self._uptime_ms or 0)
            self._told += 1

    def now(self) -> float:
        """The controller's time in seconds (the wall clock's if it has not said it yet)."""
        uptime_ms = self._uptime_ms
        return self.client.clock.now() if uptime_ms is None else uptime_ms / 1000

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Until `predicate()`, at most `timeout_s` of the controller's time."""
        start_ms = self._uptime_ms
        if start_ms is None:
            return self.client.wait_for(predicate, timeout_s)

        def waited_s() -> float:
            return (self._uptime_ms - start_ms) / 1000
        while True:
            told = self._told
            if not self.client.wait_for(lambda: predicate() or waited_s() >= timeout_s or self._told != told,
                                        CONTROLLER_SILENCE_S):
                return predicate()          # nothing has told the controller's time for that long
            if predicate():
                return True
            if waited_s() >= timeout_s:
                return False

    def no_plant(self) -> str:
        return (f"the {self.kind} target has no plant to fault from here: it has no control endpoint (real "
                "hardware has none; `aspod sim` serves one unless --no-control, named in its ASPOD-CONTROL line: "
                "give it as --aspod-control=PATH if it is not found from the target's URL)")
