"""What a bench talks to: a controller with its world, the same API whether it is simulated or real.

`LockstepTarget`: a whole world on the simulated clock (`LockstepBench`), deterministic for its seed, as
fast as the machine goes; the plant can be faulted and read. `LiveTarget`: a live controller over any
pyserial URL (an `aspod sim` on a pty or TCP port, or real hardware), in real time; its plant cannot be
faulted or read from here (the live simulator's control endpoint is not built yet), so a bench that
needs that is skipped there, never faked.

    target.call(msg) -> CommandHandle          one command, its one outcome
    target.wait_until(predicate, timeout_s)    in the target's time (simulated: runs the world)
    target.telemetry["TelemetryJoints"]        the latest of each telemetry message
    target.events                              every event, in order
    target.link_stats()                        the host link's counters
    target.run_script(text) -> dict            a teleop script, its record (host_tools/teleop/record.py)
    target.inject(fault, channel) / clear(...) plant faults by name (hil_sim/faults.py); CannotFault if not here
    target.act(name, *args)                    a plant action by name (host_tools/worlds/plant_actions.py)
    target.true_state() -> dict                the plant's truth, where there is one to read
    target.measure(name, value, unit)          a figure of the bench, for its record
"""
from __future__ import annotations

import io
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

from protocol.host_link import CommandHandle
from protocol.schema import Message

from host_tools.worlds.plant_state import plant_state
from host_tools.client.bench import BenchClient
from host_tools.client.live import HostClient
from host_tools.plugin.errors import CannotFault
from host_tools.teleop.record import ScriptRecord
from host_tools.teleop.session import run_script
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench


@dataclass
class Target:
    """A connected client (`BenchClient` or `HostClient`) and what the bench has seen through it."""
    client: Any
    kind: str
    telemetry: dict[str, Message] = field(default_factory=dict)
    measurements: dict[str, dict] = field(default_factory=dict)    # name -> {"value", "unit"}: `measure`

    def __post_init__(self) -> None:
        self.client.telemetry_listeners.append(lambda msg, now: self.telemetry.__setitem__(msg.spec.name, msg))

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

    @property
    def can_fault(self) -> bool:
        return False

    def inject(self, fault: str, channel: Optional[str] = None) -> None:
        raise CannotFault(f"the {self.kind} target has no plant to fault from here")

    def clear(self, fault: str, channel: Optional[str] = None) -> None:
        raise CannotFault(f"the {self.kind} target has no plant to fault from here")

    def act(self, name: str, *args) -> None:
        raise CannotFault(f"the {self.kind} target has no plant to act on from here")

    def true_state(self) -> dict:
        raise CannotFault(f"the {self.kind} target has no plant to read from here")

    def close(self) -> None:
        self.client.close()


class LockstepTarget(Target):
    """A whole world on the simulated clock, connected."""

    def __init__(self, seed: int = 1, plant: PlantSettings = PlantSettings()) -> None:
        self.bench = LockstepBench(seed=seed, plant=plant)
        client = BenchClient(self.bench)
        super().__init__(client, "lockstep")
        client.connect()

    def _wall_time(self):
        return self.client.wall_time

    @property
    def can_fault(self) -> bool:
        return True

    def inject(self, fault: str, channel: Optional[str] = None) -> None:
        self.bench.world.plant.inject(fault, channel)

    def clear(self, fault: str, channel: Optional[str] = None) -> None:
        self.bench.world.plant.clear(fault, channel)

    def act(self, name: str, *args) -> None:
        self.bench.act(name, *args)

    def true_state(self) -> dict:
        return plant_state(self.bench.world.plant, self.bench.plant_settings.tracker)

    def close(self) -> None:
        self.bench.close()


class LiveTarget(Target):
    """A live controller at `url` (pyserial URL or device; several links comma-separated), connected."""

    def __init__(self, url: str, psk: bytes, baud: int = 115200) -> None:
        client = HostClient(url, psk, baud=baud)
        super().__init__(client, f"live {url}")
        try:
            client.connect()
        except BaseException:
            client.close()
            raise
