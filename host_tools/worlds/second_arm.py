"""The second arm of a two-arm world (`World(second_arm=...)`, docs/two_arms.md): its own controller on its own link,
its own HAL bus and plant node, on the world's schedulers.

Each arm is what it would be alone: a controller and the plant's side of its motors on a bus of their own. What
joins them is physical, so it is the plant's: both plant nodes step on one scheduler, tick for tick (their
PLANT_SYNC ticks are one count), and the plant relays the leading controller's TRAJ_START from its arm's bus to the
other's, as a sync line between the two controllers would carry it (firmware_py/trajectory_sync.py), and either
controller's TRAJ_STOP to the other's bus. The first arm's controller leads, the second follows. With `held_object`,
the object the two hands hold (hil_sim/two_arms.py) is stepped after both plants each tick once taken, each arm's
joints carry its grasp, and each arm's wrist sensor tells its controller its grasp (GRASP_FORCE,
hil_sim/wrist_sensor.py).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable, Optional

from firmware_py.controller import Controller, ControllerConfig
from firmware_py.trajectory_sync import SyncRole
from firmware_py.uart import PacedUart, Port
from hil_sim.arm_params import ArmPlantParams
from hil_sim.hal_node import PlantNode
from hil_sim.held_object import GraspRefused, ObjectParams
from hil_sim.plant import PlantParams
from hil_sim.two_arms import EXAMPLE_BASES_M, TwoArmPlant
from hil_sim.wrist_sensor import WristSensors
from host_tools.worlds.local_bus import open_local_pair
from host_tools.worlds.nodes import build_controller, build_plant_node
from host_tools.worlds.ports import BufferPort, exchange
from host_tools.worlds.settings import PlantSettings
from protocol.host_link import HostLink
from protocol.link import LinkState
from protocol.states import GraspState
from timebase.scheduler import Scheduler

NAME = "arm2"        # the second controller's tasks on the shared schedulers: "arm2/hal", ...
OBJECT_PRIORITY = 20     # the object's task runs after both plants' (priority 10) in each tick
JAW_GAP_M = 0.02         # the part of the object the jaws close on (its thickness at the grasps)


@dataclass(frozen=True)
class SecondArm:
    """A second arm for a world: the port its controller's link is on, its controller's settings (its name and its
    part in a coordinated start are set here) and its plant's."""

    port: Port
    controller_config: Optional[ControllerConfig] = None
    plant_params: Optional[PlantParams] = None
    arm_params: Optional[ArmPlantParams] = None         # the arm the plant builds (None: ASPOD's)
    # the object both hands may hold (`SecondArmNodes.take_object`), the two arms' bases in its plane; None: none
    held_object: Optional[ObjectParams] = None
    bases_m: tuple[tuple[float, float], tuple[float, float]] = EXAMPLE_BASES_M
    # where the object waits for the hands (its centre, m, level, on a stand the arms do not feel): each hand that
    # comes within `held_object.grasp_tolerance_m` of its grasp has the object between its jaws, and once both jaws
    # close on it the two hands hold it (`aspod sim --arms 2`); None: held only by `SecondArmNodes.take_object`
    waits_at_m: Optional[tuple[float, float]] = None


def leading(config: Optional[ControllerConfig]) -> ControllerConfig:
    """The first arm's controller settings in a two-arm world: it leads the coordinated starts."""
    return dataclasses.replace(config or ControllerConfig(), trajectory_sync=SyncRole.LEADER)


class SecondArmNodes:
    """The second arm's nodes, built and started on `scheduler` (its control tasks, its plant) and `link_scheduler`
    (its comms), beside the first arm's `first_plant`."""

    def __init__(self, arm: SecondArm, psk: bytes, first_plant: PlantNode, scheduler: Scheduler,
                 link_scheduler: Scheduler, *, seed: int, baud: int, paced: bool, plant: PlantSettings,
                 direct_values: bool, nonce_source: Callable[[], bytes]) -> None:
        self.plant_bus, self.controller_bus = open_local_pair(carries_values=direct_values)
        # the solar tracker is the first arm's station's: the second arm's plant carries none
        self.plant_node = build_plant_node(self.plant_bus, seed, arm.plant_params,
                                           dataclasses.replace(plant, tracker=False), arm_params=arm.arm_params)
        self.plant = self.plant_node.plant
        scheduler.add(f"{NAME}/plant", self.plant_node.step, period_s=self.plant_node.period_s)
        self.uart = PacedUart(arm.port, baud, paced)
        config = dataclasses.replace(arm.controller_config or ControllerConfig(), name=NAME,
                                     trajectory_sync=SyncRole.FOLLOWER)
        self.controller = build_controller(psk, self.uart, self.controller_bus, config, nonce_source=nonce_source)
        self.controller.attach(scheduler, link_scheduler)
        relay_trajectory_starts(first_plant, self.plant_node)      # from the leader's bus to the follower's
        relay_trajectory_stops(first_plant, self.plant_node)       # both ways
        # the object the two hands hold: stepped after both plants each tick, once taken (`take_object`)
        self.pair: Optional[TwoArmPlant] = None
        self.holding = False
        self.waits_at_m = arm.waits_at_m
        self.on_object_event: Callable[[str], None] = lambda text: None     # each grasp's change, said
        if arm.held_object is not None:
            self.pair = TwoArmPlant((first_plant.plant.arm, self.plant.arm), arm.bases_m, arm.held_object)
            self.wrists = WristSensors(self.pair, (first_plant, self.plant_node))
            self._dt_s = self.plant_node.period_s
            scheduler.add("object", self._object_step, period_s=self._dt_s, priority=OBJECT_PRIORITY)

    def take_object(self) -> None:
        """The object between the two hands, held from now on (`TwoArmPlant.grasp`: GraspRefused, nothing changed,
        unless the hands are the grasps' distance apart); each arm's joints carry their grasp's force."""
        if self.pair is None:
            raise ValueError("this world has no object (SecondArm.held_object)")
        self.pair.grasp()
        self.holding = True
        self.on_object_event(f"the object: {self.pair.object.last_event.reason}")

    def _object_step(self, now: float) -> float:
        if self.holding:
            obj = self.pair.object
            seen = obj.event_count
            self.pair.step(self._dt_s)
            self.wrists.step()
            if obj.event_count != seen and obj.last_event is not None:
                self.on_object_event(f"the object: {obj.last_event.reason}")
            if self.waits_at_m is not None and all(state is GraspState.DROPPED for state in obj.states):
                self.holding = False             # a new one waits on the stand for the hands
                self.on_object_event(f"the object dropped; another waits at x {self.waits_at_m[0]:g}, "
                                     f"z {self.waits_at_m[1]:g} m")
        elif self.waits_at_m is not None:
            self._offer(self.waits_at_m)
        return now              # (a periodic task: anything but None keeps it)

    def _offer(self, centre_m: tuple[float, float]) -> None:
        """The object waiting at `centre_m`: between the jaws of each hand at its grasp (jaws open wide enough),
        out of them when the hand leaves without having closed on it; taken once both jaws press on it."""
        params = self.pair.object.params
        hands, _ = self.pair.hands()
        for arm, (hx, hz), (gx, gz) in zip(self.pair.arms, hands, params.grasps_m):
            at_grasp = math.hypot(hx - centre_m[0] - gx, hz - centre_m[1] - gz) <= params.grasp_tolerance_m
            if at_grasp and arm.object_width_m is None and arm.gripper_opening_m >= JAW_GAP_M:
                arm.set_object(JAW_GAP_M)
            elif not at_grasp and arm.object_width_m is not None and arm.grip_force_n == 0.0:
                arm.set_object(None)
        if all(arm.grip_force_n > params.open_jaw_n for arm in self.pair.arms):
            try:
                self.take_object()
            except GraspRefused:
                pass                # the hands closed at grasps too far apart: it waits on its stand

    def object_state(self) -> Optional[dict]:
        """The object, as JSON values (the control endpoint's `state`): its pose, velocity, squeeze, each grasp's
        state and force, and the two arms' shoulders and elbows holding it; None without an object."""
        if self.pair is None:
            return None
        obj = self.pair.object
        if not self.holding:
            return {"held": False, "waits_at_m": None if self.waits_at_m is None else list(self.waits_at_m)}
        held = any(state in (GraspState.HELD, GraspState.SLIPPING) for state in obj.states)
        x, z, theta = obj.pose
        vx, vz, w = obj.velocity
        return {"held": held, "x_m": x, "z_m": z, "angle_deg": math.degrees(theta), "vx_m_s": vx, "vz_m_s": vz,
                "w_deg_s": math.degrees(w), "squeeze_n": obj.squeeze_n,
                "shoulder_elbow_deg": [[math.degrees(float(arm.pos_rad[j])) for j in (0, 1)] for arm in self.pair.arms],
                "grasps": [{"state": state.name, "force_n": force, "limit_n": limit}
                           for state, force, limit in zip(obj.states, obj.carried_n, obj.limits_n)]}

    def close(self) -> None:
        self.plant_bus.shutdown()
        self.controller_bus.shutdown()
        self.uart.close()


def relay_trajectory_starts(source: PlantNode, to: PlantNode) -> None:
    """Every TRAJ_START `source`'s bus carries goes on `to`'s bus too (the sync line between two controllers): one
    way, from the leader's bus. Both ways, on buses that give a node its own frames back (udp_multicast), each
    relayed start would come back to be relayed again, for ever."""
    layout = to.codec.layout("TRAJ_START")
    source.on_frame("TRAJ_START", lambda values, now: to.send_frame(layout, values))


def relay_trajectory_stops(one: PlantNode, other: PlantNode) -> None:
    """A TRAJ_STOP a controller sends (`relayed` 0) on either arm's bus goes on the other's, marked relayed (1); a
    relayed one is never relayed again, so on buses that give a node its own frames back none circles."""
    for source, to in ((one, other), (other, one)):
        layout = to.codec.layout("TRAJ_STOP", ("stop_tick", "relayed"))
        source.on_frame("TRAJ_STOP", lambda values, now, to=to, layout=layout: values[1] or to.send_frame(
            layout, [values[0], 1]), ("stop_tick", "relayed"))


class SecondHost:
    """The second arm's host in a lock-step bench (`LockstepBench(arms=2).arm2`): a host link on the second
    controller's port, polled every `step_s` of the link's clock; `connect` and `call` run the bench's world as the
    bench's own do."""

    def __init__(self, host: HostLink, port: BufferPort, link_scheduler: Scheduler,
                 wait_until: Callable[..., bool], step_s: float) -> None:
        self.host, self.port, self.step_s = host, port, step_s
        self.events: list = []                 # every event the second controller sent, in order
        host.on_event = lambda msg, now: self.events.append(msg)
        self._clock = link_scheduler.clock
        self._wait_until = wait_until
        link_scheduler.add(f"{NAME}/host", self._step)

    def _step(self, now: float) -> float:
        exchange(self.port, self.host, now)
        return now + self.step_s

    def connect(self, controller: Controller, timeout_s: float = 5.0) -> bool:
        self.host.connect(self._clock.now())
        return self._wait_until(lambda: self.host.state is LinkState.UP and controller.link.session is not None
                                and controller.link.session.host_nonce == self.host.session.host_nonce, timeout_s,
                                between_loops=True)

    def call(self, msg, timeout_s: float = 30.0):
        handle = self.host.submit(msg, self._clock.now())
        self._wait_until(lambda: handle.done, timeout_s, between_loops=True)
        return handle
