"""The simulator's world: a plant and a controller meeting on a python-can bus, one scheduler.

The bus is a private `host_tools.worlds.local_bus` pair: a `can.BusABC` for one process and one
thread, much cheaper per frame than python-can's `virtual` interface (see that module). On it the
two nodes hand each other their frames' values directly, exactly what they would unpack from the
bytes (`protocol.value_frame`); `direct_values=False` makes them pack every frame, as they do
between processes (tests/test_direct_values.py runs a world both ways and compares).

Used by `aspod sim` (a pty or TCP port; the world on a `PacedClock`, simulated time paced to
the wall clock, and the link on the wall clock itself: `link_clock`, `run`) and by tests and
benches (a `SimClock`, an in-memory port, a `HostLink` driven in the same thread), so a bench
runs faster than real time and repeats exactly for a given seed.
"""
from __future__ import annotations

import math
import random
from typing import Callable, Optional

from firmware_py.controller import Controller, ControllerConfig
from timebase.scheduler import Scheduler, poll_tick, run_live
from firmware_py.uart import PacedUart, Port
from host_tools.outputs import Output
from host_tools.sessions.capture import CaptureWriter
from host_tools.sessions.impairment import ImpairedLine, ImpairedLink, Impairment
from host_tools.worlds import plant_actions
from host_tools.worlds.can_log import HalBusLog
from host_tools.worlds.fast_loop import FastLoop
from host_tools.worlds.ports import BufferPort, RecordedPort
from hil_sim.arm_params import ArmPlantParams
from hil_sim.held_object import ObjectParams
from hil_sim.plant import PlantParams
from protocol.auth import new_nonce
from protocol.host_link import HostLink
from protocol.link import LinkConfig, LinkState
from protocol.schema import Direction
from protocol.states import CloseWhy
from timebase import Clock, PacedClock, RealClock, SimClock

from host_tools.worlds.link_time import LinkScheduler, LinkTime
from host_tools.worlds.local_bus import open_local_pair
from host_tools.worlds.plant_control import PlantControl
from host_tools.worlds.second_arm import SecondArm, SecondArmNodes, SecondHost, leading
from host_tools.worlds.nodes import build_controller, build_plant_node
from host_tools.worlds.settings import PlantSettings


AFTER_THE_WORLD = 100     # a scheduler priority: after every task of the world due at the same moment


def seeded_nonces(seed: int) -> Callable[[], bytes]:
    """Nonces from a seeded generator: for reproducible lock-step runs only, never for a live link."""
    rng = random.Random(seed)
    return lambda: rng.randbytes(16)


class World:
    """Plant + controller on one scheduler, the controller's UART on `port`.

    With `link_clock` (the wall clock, when `clock` is a `PacedClock`), the controller's comms
    task runs on a second scheduler on it (`link_scheduler`): `run(should_stop)` runs both. With
    `link_time` instead (lock-step, re-simulating a real-time recording: `link_time.py`), it runs on
    the one scheduler with its times on a link clock of its own.
    `direct_values`: the nodes hand each other values, not packed frames (see the module docstring).
    `fast_loop`: a deterministic, compiled world runs its 1 kHz tasks in `FastLoop` between events (the same to the
    bit; False: tick by tick).
    """

    def __init__(self, clock: Clock, port: Port, psk: bytes, *, seed: int = 0, baud: int = 115200,
                 paced: bool = True, controller_config: Optional[ControllerConfig] = None,
                 plant_params: Optional[PlantParams] = None, deterministic: bool = False,
                 plant: PlantSettings = PlantSettings(), link_clock: Optional[Clock] = None,
                 direct_values: bool = True, link_time: Optional[LinkTime] = None, fast_loop: bool = True,
                 second_arm: Optional[SecondArm] = None, arm_params: Optional[ArmPlantParams] = None) -> None:
        self.clock = clock
        self.hal_log: Optional[HalBusLog] = None
        self.plant_bus, self.controller_bus = open_local_pair(carries_values=direct_values)
        self.plant_node = build_plant_node(self.plant_bus, seed, plant_params, plant, arm_params=arm_params)
        self.plant = self.plant_node.plant
        # deterministic: on a simulated clock a task takes no time; nothing to measure
        self.scheduler = Scheduler(clock, stopwatch=None if deterministic else RealClock.precise_now)
        self.scheduler.add("plant", self.plant_node.step, period_s=self.plant_node.period_s)
        self.uart = PacedUart(port, baud, paced)
        if second_arm is not None:
            controller_config = leading(controller_config)
        nonces = seeded_nonces(seed) if deterministic else new_nonce
        self.controller = build_controller(psk, self.uart, self.controller_bus, controller_config, nonce_source=nonces)
        self.link_scheduler = (Scheduler(link_clock) if link_clock is not None
                               else LinkScheduler(self.scheduler, link_time) if link_time is not None
                               else self.scheduler)
        self.controller.attach(self.scheduler, self.link_scheduler)
        # the second arm: its own controller, link, bus and plant node, on these schedulers (second_arm.py)
        self.arm2: Optional[SecondArmNodes] = None
        if second_arm is not None:
            self.arm2 = SecondArmNodes(second_arm, psk, self.plant_node, self.scheduler, self.link_scheduler,
                                       seed=seed + 1, baud=baud, paced=paced, plant=plant,
                                       direct_values=direct_values,
                                       # (seed + 1 and + 2: the bench's hosts'; each end its own nonces)
                                       nonce_source=seeded_nonces(seed + 3) if deterministic else new_nonce)
        # the three 1 kHz tasks many ticks a call between events (host_tools/worlds/fast_loop.py): deterministic and
        # compiled only, one arm
        self.fast_loop: Optional[FastLoop] = None
        if deterministic and fast_loop and second_arm is None and FastLoop.fits(self):
            self.fast_loop = FastLoop(self)
            self.scheduler.run_ahead(("arm", "plant", "hal"), self.fast_loop.run)

    def log_hal_bus(self, output: Output, ids: Optional[frozenset[int]] = None,
                    rotate_bytes: Optional[int] = None) -> HalBusLog:
        """Write every HAL frame (of `ids` only, if given) from now on to `output` through python-can's Logger
        (`close` puts it in place); with `rotate_bytes`, in parts of about that size (can_log.py)."""
        self.hal_log = HalBusLog(output, self.clock, {"plant": self.plant_bus, "controller": self.controller_bus},
                                 ids, rotate_bytes)
        return self.hal_log

    def record_link(self, capture: CaptureWriter) -> None:
        """Keep every byte of the controller's line in `capture`, stamped with the world's time."""
        self.uart.port = RecordedPort(self.uart.port, capture, self.clock)

    def run(self, should_stop: Callable[[], bool]) -> None:
        """Run the world (and its link, on its own clock) until `should_stop()`."""
        if isinstance(self.clock, PacedClock):
            self.clock.start()
        run_live(self.scheduler, self.link_scheduler, should_stop)

    def close(self) -> None:
        if self.hal_log is not None:
            self.hal_log.stop()
        self.plant_bus.shutdown()
        self.controller_bus.shutdown()
        self.uart.close()
        if self.arm2 is not None:
            self.arm2.close()


class LockstepBench:
    """A whole world on a `SimClock` with a host link over an in-memory line.

    `wait_until(predicate, timeout_s)` runs the world in simulated time; `call(msg)`
    sends a command and runs until it has its outcome. Bytes between host and
    controller pass through `to_controller` and `to_host` (callables bytes -> bytes,
    e.g. a lossy link emulator).

    `direct_values` and `fast_loop` as in `World`. With `link_time` the controller's comms task and the host run on a
    link clock of their own (`World`, `link_time.py`): `aspod replay` of a real-time recording.

    The host and the controller's comms task poll the line every `step_s` and 1 ms. With
    `sleeping_line` (the default) the line says when bytes move, and both skip the polls
    that would find nothing (most of them): the same polls do the same work, to the byte
    (tests/test_world.py). In the lock-step bench's moving world the two cost about 5 us of
    each simulated millisecond so, against 18 us polling (and the scheduler runs 1.9 tasks
    fewer per millisecond).
    """

    MAX_IDLE_S = 0.05     # the host looks at the line at least this often, whatever its timers say

    def __init__(self, psk: bytes = b"bench-key-0123456789abcdef", *, seed: int = 0, baud: int = 115200,
                 paced: bool = True, controller_config: Optional[ControllerConfig] = None,
                 host_config: Optional[LinkConfig] = None,
                 to_controller: Callable[[bytes], bytes] = lambda b: b,
                 to_host: Callable[[bytes], bytes] = lambda b: b, step_s: float = 0.001,
                 plant_params: Optional[PlantParams] = None, plant: PlantSettings = PlantSettings(),
                 sleeping_line: bool = True, clock: Optional[SimClock] = None,
                 direct_values: bool = True, impairment: Optional[Impairment] = None,
                 link_time: Optional[LinkTime] = None, fast_loop: bool = True, arms: int = 1,
                 arm_params: Optional[ArmPlantParams] = None, held_object: Optional[ObjectParams] = None,
                 object_waits_at_m: Optional[tuple[float, float]] = None) -> None:
        if arms not in (1, 2):
            raise ValueError(f"a bench has 1 or 2 arms, not {arms}")
        self.clock = clock if clock is not None else SimClock()
        self.port = BufferPort(notifies=sleeping_line)
        port2 = BufferPort(notifies=False) if arms == 2 else None
        self.world = World(self.clock, self.port, psk, seed=seed, baud=baud, paced=paced,
                           controller_config=controller_config, deterministic=True, plant_params=plant_params,
                           plant=plant, direct_values=direct_values, link_time=link_time, fast_loop=fast_loop,
                           arm_params=arm_params,
                           second_arm=None if port2 is None else SecondArm(port2, controller_config, plant_params,
                                                                           arm_params, held_object,
                                                                           waits_at_m=object_waits_at_m))
        self.link_clock = self.world.link_scheduler.clock    # the host's time: the world's, unless `link_time`
        self.events: list = []
        self.telemetry: list = []
        self.host = HostLink(psk, host_config, nonce_source=seeded_nonces(seed + 1),
                             on_telemetry=lambda m, now: self.telemetry.append(m),
                             on_event=lambda m, now: self.events.append(m))
        self.to_controller = to_controller
        self.to_host = to_host
        self.plant_settings = plant
        self._capture: Optional[CaptureWriter] = None
        # `sim ...` lines and a bench's faults, as the live simulator's control endpoint takes them
        self.control = PlantControl(self.world.plant, self.clock, tracker=plant.tracker, about={"world": "lockstep"},
                                    on_change=self._note_control,
                                    held_object=None if self.world.arm2 is None else self.world.arm2.object_state)
        self.step_s = step_s
        self._host_alive = True
        self._host_running = False
        self._host_last_s: Optional[float] = None
        self._sent_to_no_one: Callable[[bytes], None] = lambda data: None     # while the host is gone (`record`)
        self.world.link_scheduler.add("host", self._host_step)
        # the second arm's host (`arms=2`), on its own link: `bench.arm2.call(msg)`
        self.arm2: Optional[SecondHost] = None
        if port2 is not None:
            self.arm2 = SecondHost(HostLink(psk, host_config, nonce_source=seeded_nonces(seed + 2)), port2,
                                   self.world.link_scheduler, self.wait_until, step_s)
        # An impaired line (aspod proxy's model) between them: bytes go in when written and come out when due.
        self.line = None if impairment is None else ImpairedLink(impairment)
        if self.line is not None:
            self.world.scheduler.add("line", self._line_step, math.inf)
        # The host runs when bytes reach it, when its link has work, and when its timers are due.
        self.sleeping_line = sleeping_line
        if sleeping_line:
            self.port.on_output = self.host.on_work = self._host_work

    @property
    def host_alive(self) -> bool:
        """False: the host is gone (its bytes are lost, it neither reads nor sends); True again: it is back."""
        return self._host_alive

    @host_alive.setter
    def host_alive(self, alive: bool) -> None:
        self._host_alive = alive
        if self.sleeping_line:
            self._host_work()

    def _host_work(self) -> None:
        """Bytes for the host or work for its link: it runs at its next poll (during a run, the run sees to it)."""
        if not self._host_running:
            now, last = self.link_clock.now(), self._host_last_s
            self.world.link_scheduler.wake("host", now if last is None else poll_tick(last, self.step_s, now,
                                                                                      after=True))

    @property
    def controller(self) -> Controller:
        return self.world.controller

    def _host_step(self, now: float) -> float:
        """Bytes from the controller in, the host link's timers, its frames out.

        The host polls every `step_s`; on a sleeping line it sleeps through the polls that
        would find nothing: until the first at or after its link's next timer, unless bytes
        or work wake it first (as the controller's comms task does: firmware_py/comms.py).
        """
        self._host_last_s = now
        if self._host_alive:
            self._host_running = True
            try:
                if self.port.outbox:
                    data = self.to_host(bytes(self.port.outbox))
                    self.port.outbox.clear()
                    if self.line is not None:
                        self._into_line(self.line.to_host, data, now)
                    elif data:
                        self.host.feed(data, now)
                if self.line is not None:
                    data = self.line.to_host.receive(now)
                    if data:
                        self.host.feed(data, now)
                self.host.poll(now)
                out = self.host.take_all(now)
                if out and self.line is not None:
                    self._into_line(self.line.to_controller, out, now)
                elif out:
                    self.port.deliver(self.to_controller(out))
            finally:
                self._host_running = False
        else:
            if self.port.outbox:
                self._sent_to_no_one(bytes(self.port.outbox))
            self.port.outbox.clear()
        if not self.sleeping_line:
            return now + self.step_s
        timer = self.host.next_timer_s() if self._host_alive else math.inf
        return poll_tick(now, self.step_s, min(timer, now + self.MAX_IDLE_S))

    def record(self, capture: CaptureWriter) -> None:
        """Keep the line's bytes in `capture`, stamped with the simulated time, as the controller's end sees them
        (what it received, after `to_controller`; what it sent, before `to_host`, also while no host is there to
        take it), as `aspod sim --record` does."""
        to_controller, to_host, now = self.to_controller, self.to_host, self.clock.now
        self._sent_to_no_one = lambda data: capture.write("link", Direction.TO_HOST, data, now())

        def received(data: bytes) -> bytes:
            data = to_controller(data)
            capture.write("link", Direction.TO_CONTROLLER, data, now())
            return data

        def sent(data: bytes) -> bytes:
            capture.write("link", Direction.TO_HOST, data, now())
            return to_host(data)
        self.to_controller, self.to_host = received, sent
        self._capture = capture

    def act(self, name: str, *args) -> None:
        """Do a plant action by name (host_tools/worlds/plant_actions.py); recorded as a world event."""
        plant_actions.act(self.world.plant, name, *args)
        if self._capture is not None:
            self._capture.note({"action": name, "args": list(args)}, self.clock.now())

    def _note_control(self, request: dict) -> None:
        """A change done through `control`, recorded as a world event, as `act` records an action."""
        if self._capture is not None:
            self._capture.note({"control": request}, self.clock.now())

    def redo(self, event: dict) -> None:
        """Do again a world event this bench recorded (`aspod replay`); ValueError if it cannot be done."""
        if "control" in event:
            reply = self.control.request(event["control"])
            if not reply["ok"]:
                raise ValueError(reply["error"])
            return
        self.act(str(event.get("action")), *event.get("args", ()))

    def settings(self) -> dict:
        """What `aspod replay` needs to build this world again (a capture's settings): the plant and every
        controller parameter's value now."""
        return {"plant": self.plant_settings.to_dict(), "params": self.controller.params.values()}

    def _into_line(self, line: ImpairedLine, data: bytes, now: float) -> None:
        line.send(data, now)
        self.world.scheduler.wake("line", line.next_due_s())

    def _line_step(self, now: float) -> float:
        """Bytes the impaired line delivers now: to the controller's port, or to the host (woken for them)."""
        data = self.line.to_controller.receive(now)
        if data:
            self.port.deliver(self.to_controller(data))
        if self.line.to_host.next_due_s() <= now:
            self.world.scheduler.wake("host", now)
        return self.line.next_due_s()

    def run_for(self, duration_s: float) -> None:
        self.world.scheduler.run_until(self.clock.now() + duration_s)

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float, *, between_loops: bool = False) -> bool:
        """Run in simulated time until `predicate()` holds (True) or `timeout_s` passes (False), looking at it every
        `step_s`. `between_loops`: the predicate reads only what tasks other than the 1 kHz loops change (what the
        host has received, the supervisor's state), so it is looked at only after the steps in which one of them ran
        (the same steps, where it could change): in between, the fast loop runs many ticks a call."""
        end = self.clock.now() + timeout_s
        scheduler, step_s = self.world.scheduler, self.step_s
        while not predicate():
            now = self.clock.now()
            if now >= end:
                return False
            if not between_loops:
                scheduler.run_until(min(end, now + step_s))
                continue
            steps = [min(end, now + step_s)]        # the steps' ends, added up as the loop above adds them

            def step_end(at: float) -> float:
                last = steps[0]
                while last < at and last < end:
                    last = steps[0] = min(end, last + step_s)
                return last
            scheduler.run_until(end, bound=step_end)
        return True

    def connect(self, timeout_s: float = 5.0) -> bool:
        self.host.connect(self.link_clock.now())
        return self.wait_until(lambda: self.host.state is LinkState.UP and self.controller.link.session is not None
                               and self.controller.link.session.host_nonce == self.host.session.host_nonce,
                               timeout_s, between_loops=True)

    def call(self, msg, timeout_s: float = 30.0):
        handle = self.host.submit(msg, self.link_clock.now())
        self.wait_until(lambda: handle.done, timeout_s, between_loops=True)
        return handle

    def close_session(self, why: CloseWhy = CloseWhy.DONE, timeout_s: float = 5.0, host: Optional[HostLink] = None
                      ) -> bool:
        """End the host's session cleanly (`HostLink.close`; `host`: another of this world's hosts, the second
        arm's) and run until it is closed: True once CLOSED."""
        host = self.host if host is None else host
        if host.state is not LinkState.UP:
            return host.state is LinkState.CLOSED
        host.close(self.clock.now(), why)
        self.wait_until(lambda: host.state is not LinkState.CLOSING, timeout_s, between_loops=True)
        return host.state is LinkState.CLOSED

    def close(self) -> None:
        self.world.close()
        if self._capture is not None:
            self._capture.close()
