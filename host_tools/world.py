"""The simulator's world: a plant and a controller meeting on a python-can bus, one scheduler.

The bus is a private `host_tools.local_bus` pair: a `can.BusABC` for one process and one
thread, much cheaper per frame than python-can's `virtual` interface (see that module).

Used by `aspod sim` (real time, a pty or TCP port) and by tests and benches (a
`SimClock`, an in-memory port, a `HostLink` driven in the same thread), so a bench
runs faster than real time and repeats exactly for a given seed.
"""
from __future__ import annotations

import random
from typing import Callable, Optional

from firmware_py.controller import Controller, ControllerConfig
from firmware_py.scheduler import Scheduler
from firmware_py.uart import BufferPort, PacedUart, Port
from hil_sim.plant import PlantParams
from hil_sim.sun import DEFAULT_START, DateTimeLike
from protocol.auth import new_nonce
from protocol.host_link import HostLink
from protocol.link import LinkConfig, LinkState
from timebase import Clock, RealClock, SimClock

from host_tools.local_bus import open_local_pair
from host_tools.nodes import build_controller, build_plant_node


def seeded_nonces(seed: int) -> Callable[[], bytes]:
    """Nonces from a seeded generator: for reproducible lock-step runs only, never for a live link."""
    rng = random.Random(seed)
    return lambda: rng.randbytes(16)


class World:
    """Plant + controller on one scheduler, the controller's UART on `port`."""

    def __init__(self, clock: Clock, port: Port, psk: bytes, *, seed: int = 0, baud: int = 115200,
                 paced: bool = True, controller_config: Optional[ControllerConfig] = None,
                 plant_params: Optional[PlantParams] = None, deterministic: bool = False,
                 gravity: str = "earth", payload_kg: float = 0.0, tracker: bool = True,
                 start: DateTimeLike = DEFAULT_START, clouds=None) -> None:
        self.clock = clock
        self.plant_bus, self.controller_bus = open_local_pair()
        self.plant_node = build_plant_node(self.plant_bus, seed, plant_params, gravity=gravity, payload_kg=payload_kg,
                                           tracker=tracker, start=start, clouds=clouds)
        self.plant = self.plant_node.plant
        stopwatch = clock.now if deterministic else RealClock.precise_now
        self.scheduler = Scheduler(clock, stopwatch=stopwatch)
        self.scheduler.add("plant", self.plant_node.step, period_s=self.plant_node.period_s)
        self.uart = PacedUart(port, baud, paced)
        self.controller = build_controller(psk, self.uart, self.controller_bus, controller_config,
                                           nonce_source=seeded_nonces(seed) if deterministic else new_nonce)
        self.controller.attach(self.scheduler)

    def close(self) -> None:
        self.plant_bus.shutdown()
        self.controller_bus.shutdown()
        self.uart.close()


class LockstepBench:
    """A whole world on a `SimClock` with a host link over an in-memory line.

    `wait_until(predicate, timeout_s)` runs the world in simulated time; `call(msg)`
    sends a command and runs until it has its outcome. Bytes between host and
    controller pass through `line` (a callable bytes -> bytes, e.g. a lossy link
    emulator) in each direction.
    """

    def __init__(self, psk: bytes = b"bench-key-0123456789abcdef", *, seed: int = 0, baud: int = 115200,
                 paced: bool = True, controller_config: Optional[ControllerConfig] = None,
                 host_config: Optional[LinkConfig] = None,
                 to_controller: Callable[[bytes], bytes] = lambda b: b,
                 to_host: Callable[[bytes], bytes] = lambda b: b, step_s: float = 0.001,
                 gravity: str = "earth", payload_kg: float = 0.0,
                 plant_params: Optional[PlantParams] = None, tracker: bool = True,
                 start: DateTimeLike = DEFAULT_START, clouds=None) -> None:
        self.clock = SimClock()
        self.port = BufferPort()
        self.world = World(self.clock, self.port, psk, seed=seed, baud=baud, paced=paced,
                           controller_config=controller_config, deterministic=True, gravity=gravity,
                           payload_kg=payload_kg, plant_params=plant_params, tracker=tracker, start=start,
                           clouds=clouds)
        self.events: list = []
        self.telemetry: list = []
        self.host = HostLink(psk, host_config, nonce_source=seeded_nonces(seed + 1),
                             on_telemetry=lambda m, now: self.telemetry.append(m),
                             on_event=lambda m, now: self.events.append(m))
        self.to_controller = to_controller
        self.to_host = to_host
        self.step_s = step_s
        self.host_alive = True
        self.world.scheduler.add("host", self._host_step)

    @property
    def controller(self) -> Controller:
        return self.world.controller

    def _host_step(self, now: float) -> float:
        if self.host_alive:
            if self.port.outbox:
                data = self.to_host(bytes(self.port.outbox))
                self.port.outbox.clear()
                if data:
                    self.host.feed(data, now)
            self.host.poll(now)
            out = self.host.take_all(now)
            if out:
                self.port.inbox += self.to_controller(out)
        else:
            self.port.outbox.clear()
        return now + self.step_s

    def run_for(self, duration_s: float) -> None:
        self.world.scheduler.run_until(self.clock.now() + duration_s)

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Run in simulated time until `predicate()` holds (True) or `timeout_s` passes (False)."""
        end = self.clock.now() + timeout_s
        while not predicate():
            if self.clock.now() >= end:
                return False
            self.world.scheduler.run_until(min(end, self.clock.now() + self.step_s))
        return True

    def connect(self, timeout_s: float = 5.0) -> bool:
        self.host.connect(self.clock.now())
        return self.wait_until(lambda: self.host.state is LinkState.UP and self.controller.link.session is not None
                               and self.controller.link.session.host_nonce == self.host.session.host_nonce,
                               timeout_s)

    def call(self, msg, timeout_s: float = 30.0):
        handle = self.host.submit(msg, self.clock.now())
        self.wait_until(lambda: handle.done, timeout_s)
        return handle

    def close(self) -> None:
        self.world.close()
