"""Building the two HAL nodes, the same way for every world.

`aspod plant` (the plant alone) and `aspod firmware` (the controller alone) get their
bus from `open_bus`, `World` (one process, one thread) a private pair from
`host_tools.worlds.local_bus.open_local_pair`; all of them build the plant with
`build_plant_node` and the controller with `build_controller`, so a plant in its own
process is the very plant `aspod sim` runs in-process.

Buses. Any python-can interface works, opened for CAN FD (MOTOR_CMD and MOTOR_FB are
16- and 48-byte FD frames). Two need care:

* `virtual` joins only buses of the same process (across its threads), useless between
  processes (`open_bus` refuses it there: see `IN_PROCESS_ONLY`).
* `udp_multicast` (python-can's `multicast` extra, msgpack) carries frames between
  processes over IP multicast, on loopback or a LAN. The channel is a multicast group
  (239.0.0.0/8 or ff00::/8), the `port` keyword the UDP port. Every sender gets its own
  frames back, which no real CAN controller does by default; `open_bus(..., node=...)`
  then wraps the bus in `OwnEchoFilter`, which drops (and counts) the frames the DBC
  declares as sent by that node, so the node's counters count only what others sent.
"""
from __future__ import annotations

import importlib
import inspect
import ipaddress
import random
import re
import socket
from typing import Any, Callable, Iterable, Optional

import can
import numpy as np

from firmware_py.controller import Controller, ControllerConfig
from firmware_py.hal import ControllerHal
from firmware_py.uart import PacedUart
from hil_sim.arm_params import ARM_PLANT_PARAMS, ArmPlantParams
from hil_sim.hal_node import PlantNode
from hil_sim.plant import Plant, PlantParams
from protocol.auth import new_nonce
from protocol.errors import shown
from protocol.hal import BusView, HalCodec

from host_tools.worlds.settings import PlantSettings

PLANT = "PLANT"            # node names as the DBC declares them (BU_)
CONTROLLER = "CONTROLLER"
NODES = (PLANT, CONTROLLER)

# Interfaces whose buses meet only inside one process.
IN_PROCESS_ONLY = frozenset({"virtual"})
# Interfaces on which a node receives the frames it sent itself.
ECHOES_OWN_FRAMES = frozenset({"udp_multicast"})
# python-can's default port for udp_multicast.
UDP_MULTICAST_DEFAULT_PORT = 43113

PLANT_PERIOD_S = 0.001                  # the plant's tick (1 kHz)


class BusOpenError(OSError):
    """The interface exists but the bus cannot be opened here (no driver, no device, no network)."""


MAX_ECHOES_PER_RECV = 256     # own echoes one `recv` drops at most before it returns None (as if nothing waited)


class OwnEchoFilter(BusView):
    """A bus that drops the frames the DBC declares as sent by `node` (its own echoes).

    For interfaces on which every sender receives its own frames (udp_multicast). Dropped
    frames are counted in `own_echoes`; everything else (frames of the other node,
    undeclared IDs, error frames) passes, so bad frames are still counted by the node.
    Everything but `recv` is the wrapped bus's own. A positive `recv` timeout restarts
    after each dropped echo (the HAL nodes only ever poll with timeout 0). After `MAX_ECHOES_PER_RECV` echoes
    in a row it returns None: a flood of frames with the node's own IDs (another node sending them) left the
    node's poll in this loop for as long as it lasted (a plant stalled 20 s, its controller HAL_STALE).
    """

    def __init__(self, bus: can.BusABC, node: str, codec: Optional[HalCodec] = None) -> None:
        codec = codec or HalCodec()
        own = codec.ids_sent_by(node) - codec.ids_between_peers(node)     # (a peer's TRAJ_START passes)
        if not own:
            raise ValueError(f"no HAL frame is declared as sent by {node!r}; nodes: {', '.join(NODES)}")
        super().__init__(bus)
        self.node = node
        self.own_ids = own
        self.own_echoes = 0
        self.own_sent = 0       # frames with the node's own IDs sent through this filter (each may echo once)

    def send(self, msg: can.Message, timeout: Optional[float] = None) -> None:
        self.bus.send(msg, timeout)
        if msg.arbitration_id in self.own_ids:
            self.own_sent += 1

    def recv(self, timeout: Optional[float] = None) -> Optional[can.Message]:
        for _ in range(MAX_ECHOES_PER_RECV):
            msg = self.bus.recv(timeout)
            if (msg is None or msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame
                    or msg.arbitration_id not in self.own_ids):
                return msg
            self.own_echoes += 1
        return None     # a stream of frames with the node's own IDs (another node sending them) must not starve it


def own_echoes(bus: Any) -> int:
    """Own frames dropped on `bus` so far (0 for a bus that does not echo them); `bus` may be wrapped
    (a lock-step `SyncTap` passes its bus's attributes through)."""
    count = getattr(bus, "own_echoes", 0)
    return count if isinstance(count, int) else 0


def check_interface(interface: str, *, between_processes: bool = False) -> str:
    """`interface` if python-can knows it (and it can join other processes, if asked); else ValueError."""
    valid = can.interfaces.VALID_INTERFACES
    if interface not in valid:
        raise ValueError(f"unknown python-can interface {interface!r}; known: {', '.join(sorted(valid))}")
    if between_processes and interface in IN_PROCESS_ONLY:
        raise ValueError(f"interface {interface!r} joins only buses in the same process; between processes "
                         "use udp_multicast (or real CAN: socketcan, pcan, ...); `aspod sim` without --hal "
                         "runs plant and controller in one process on a private in-process bus")
    return interface


def open_bus(interface: str, channel: str, *, node: Optional[str] = None, bitrate: Optional[int] = None,
             data_bitrate: Optional[int] = None, between_processes: bool = True, **kwargs: Any) -> can.BusABC:
    """Open a python-can bus for the HAL (CAN FD) on `interface` / `channel`.

    `node` (PLANT or CONTROLLER) says who will use it: on an interface that echoes
    a sender's own frames, the bus comes wrapped in `OwnEchoFilter`. `bitrate` and
    `data_bitrate` (the FD data phase) go to the interface only if given; `kwargs`
    go as they are (udp_multicast: `port`, `hop_limit`; socketcand: `host`, `port`; ...).

    Raises ValueError for settings that cannot be right (unknown interface, a
    udp_multicast channel that is not a multicast group, keywords the interface
    refuses), `BusOpenError` (an OSError) when the bus cannot be opened here.
    """
    check_interface(interface, between_processes=between_processes)
    if node is not None and node not in NODES:
        raise ValueError(f"unknown node {node!r}; nodes: {', '.join(NODES)}")
    options: dict[str, Any] = dict(kwargs)
    if bitrate is not None:
        options["bitrate"] = bitrate
    if data_bitrate is not None:
        options["data_bitrate"] = data_bitrate
    if interface == "virtual":
        options.setdefault("receive_own_messages", False)
        options.setdefault("protocol", can.CanProtocol.CAN_FD)
    else:
        options.setdefault("fd", True)
        if options["fd"] is not True:
            raise ValueError(f"fd={options['fd']!r}: the HAL bus is always CAN FD (MOTOR_CMD has 16 data bytes, "
                             "MOTOR_FB 48)")
    if "can_filters" in options:
        raise ValueError("can_filters: the HAL nodes read every frame on the bus (they count the ones they do "
                         "not take); a filter would hide frames from them")
    if options.get("receive_own_messages"):
        raise ValueError("receive_own_messages: a HAL node does not take its own frames (it drops the echoes some "
                         "interfaces give; udp_multicast cannot give them at all)")
    if interface == "udp_multicast":
        _check_udp_multicast(channel, options)
    try:
        bus = can.Bus(interface=interface, channel=channel, **options)
    except TypeError as exc:
        raise ValueError(f"interface {interface!r} refuses these settings {options}: {exc}") from exc
    except (can.CanError, OSError, ImportError) as exc:
        raise BusOpenError(f"cannot open the {interface} bus on channel {channel!r}: {exc}"
                           + (f" ({exc.__cause__})" if exc.__cause__ else "")) from exc
    except Exception as exc:     # a driver that fails in its own way (python-can's kvaser without canlib: NameError)
        raise BusOpenError(f"cannot open the {interface} bus on channel {channel!r}: its python-can driver failed "
                           f"({type(exc).__name__}: {exc}); is the vendor's library installed?") from exc
    if node is not None and interface in ECHOES_OWN_FRAMES:
        return OwnEchoFilter(bus, node)   # type: ignore[return-value]
    return bus


def _check_udp_multicast(channel: str, options: dict[str, Any]) -> None:
    try:
        group = ipaddress.ip_address(channel)
    except ValueError:
        group = None
    if group is None or not group.is_multicast:
        raise ValueError(f"udp_multicast: channel {channel!r} is not a multicast group address "
                         "(IPv4 224.0.0.0/4, e.g. 239.74.163.2, or IPv6 ff00::/8)")
    if getattr(group, "scope_id", None):
        raise ValueError(f"udp_multicast: channel {channel!r}: python-can's udp_multicast takes no scope "
                         "(%interface) in the group address")
    port = options.get("port", UDP_MULTICAST_DEFAULT_PORT)
    if not isinstance(port, int) or isinstance(port, bool) or not 1 <= port <= 65535:
        raise ValueError(f"udp_multicast: port {port!r} is not a whole number in 1..65535")
    hops = options.get("hop_limit", 1)
    if not isinstance(hops, int) or isinstance(hops, bool) or not 0 <= hops <= 255:
        raise ValueError(f"udp_multicast: hop_limit {hops!r} is not a whole number in 0..255")


def fresh_udp_multicast() -> tuple[str, int]:
    """A multicast group and a UDP port for one private udp_multicast bus.

    On Linux a socket bound to a port receives every group joined on the host at that
    port, so it is the port that keeps two runs apart: take one the kernel says is free
    now. The group is random within 239.255.0.0/16 (organisation-local scope).
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("", 0))
        port = probe.getsockname()[1]
    rng = random.SystemRandom()
    return f"239.255.{rng.randrange(256)}.{rng.randrange(1, 255)}", port


def describe_bus(interface: str, channel: str, options: Optional[dict[str, Any]] = None) -> str:
    """`interface=... channel=... key=value ...`, for readiness lines and logs."""
    extra = "".join(f" {key}={value}" for key, value in sorted((options or {}).items()))
    return f"interface={interface} channel={channel}{extra}"


# ---- the plant ----

def build_plant(seed: int = 0, params: Optional[PlantParams] = None,
                settings: PlantSettings = PlantSettings(), arm_params: Optional[ArmPlantParams] = None) -> Plant:
    """The plant, its noise seeded with `seed`; the arm, the tracker, its sun and clouds as `settings` say
    (its start resolved: `PlantSettings.with_start`); the arm built as `arm_params` say (None: ASPOD's)."""
    rng = np.random.default_rng(seed)
    return Plant(params or PlantParams(), rng, arm_params=arm_params or ARM_PLANT_PARAMS, gravity=settings.gravity,
                 payload_kg=settings.payload_kg, start=settings.plant_start(), clouds=settings.clouds)


def build_plant_node(bus: can.BusABC, seed: int = 0, params: Optional[PlantParams] = None,
                     settings: PlantSettings = PlantSettings(), *, period_s: float = PLANT_PERIOD_S,
                     lockstep: bool = False, arm_params: Optional[ArmPlantParams] = None) -> PlantNode:
    """The plant on `bus`; add its `step` to a scheduler (`scheduler.add("plant", node.step, period_s=node.period_s)`).

    `settings.tracker` puts the solar tracker on the bus too (TRACKER_CMD in, TRACKER_SENSE and
    TRACKER_POS out every 10 ms); without it the plant is the arm, mount and gripper alone.
    `lockstep` says so in PLANT_SYNC (the plant's clock does the waiting: `protocol.lockstep`).
    """
    plant = build_plant(seed, params, settings, arm_params)
    return PlantNode(bus, plant, period_s, tracker=settings.tracker, lockstep=lockstep)


# ---- the controller ----

def build_controller(psk: bytes, uart: PacedUart, bus: can.BusABC, config: Optional[ControllerConfig] = None, *,
                     nonce_source: Callable[[], bytes] = new_nonce) -> Controller:
    """The controller with its HAL on `bus` and its link on `uart`; `controller.attach(scheduler)` starts it.

    A port that guards its line against takeover (`TcpServerPort.live_session`, `vouch`) is told here
    about the controller's session and how to judge a newcomer's frames: every world (`aspod sim`, `aspod firmware`, `World`) builds
    its controller through this function, after it opened the port."""
    controller = Controller(psk, uart, ControllerHal(bus), config, nonce_source=nonce_source)
    if hasattr(uart.port, "live_session"):
        link = controller.link
        uart.port.live_session = lambda: link.session if link.session is not None and not link.link_lost else None
        uart.port.vouch = link.vouch
    return controller


def hal_counters(endpoint: Any) -> dict[str, int]:
    """A HAL node's counters (PlantNode or ControllerHal), own echoes included."""
    return {"frames_sent": endpoint.frames_sent, "frames_received": endpoint.frames_received,
            "own_echoes": own_echoes(endpoint.bus), "bad_frames": endpoint.bad_frames,
            "bus_errors": endpoint.bus_errors}


def format_counters(counters: dict[str, Any]) -> str:
    return " ".join(f"{key}={value}" for key, value in counters.items())


def parse_bus_args(items: Iterable[str], interface: Optional[str] = None, option: str = "--bus-arg") -> dict[str, Any]:
    """`KEY=VALUE` strings (--bus-arg, --hal-arg) to constructor keywords: ints, floats, true/false, else text.

    With `interface`, every KEY must be one the interface's bus takes (`bus_keywords`): python-can
    buses take **kwargs and silently ignore what they do not know, so a misspelt keyword would
    change nothing and say nothing. ValueError naming `option`, and the keywords known, else."""
    options: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key.isidentifier():
            raise ValueError(f"{option} {shown(item)} is not KEY=VALUE (e.g. port=43113)")
        if key in ("interface", "channel"):
            raise ValueError(f"{option} {key!r}: use --{key} (or --hal/--hal-channel) instead")
        options[key] = _guess_value(text.strip())
    known = bus_keywords(interface) if interface is not None and options else None
    unknown = sorted(set(options) - known) if known is not None else []
    if unknown:
        raise ValueError(f"{option} {', '.join(unknown)}: the {interface} bus takes no such keyword; it takes "
                         f"{', '.join(sorted(known))}")
    return options


_DOC_PARAM = re.compile(r":param\s+(?:[^:\n]*\s)?(\w+)\s*:")    # `:param int bitrate:` in a docstring


def bus_keywords(interface: str) -> Optional[frozenset[str]]:
    """The keywords a python-can bus of `interface` takes: its class's constructor's named parameters, the ones
    its docstrings document (`:param fd:`) when the constructor takes them through **kwargs (kvaser, pcan,
    ...), and those every bus takes (BusABC's, and `can.Bus`'s own); `channel` aside. None if the class cannot
    be loaded here (its driver is missing, say: opening the bus will say so)."""
    try:
        module, name = can.interfaces.BACKENDS[interface]
        cls = getattr(importlib.import_module(module), name)
    except (KeyError, ImportError, AttributeError, OSError):
        return None
    named = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    own = inspect.signature(cls.__init__).parameters.values()
    keywords = {p.name for function in (cls.__init__, can.BusABC.__init__, can.Bus)
                for p in inspect.signature(function).parameters.values() if p.kind in named}
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in own):
        keywords |= set(_DOC_PARAM.findall((cls.__init__.__doc__ or "") + (cls.__doc__ or "")))
    return frozenset(keywords - {"self", "channel", "interface"})


def _guess_value(text: str) -> Any:
    lowered = text.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text
