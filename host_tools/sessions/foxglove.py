"""A session as Foxglove sees it: the controller's telemetry and events on Foxglove topics, with its schemas.

One mapping (`FoxgloveTopics.add`) from decoded frames (host_tools/sessions/decode.py) to Foxglove messages, used
by `aspod log --mcap` (a capture written as an MCAP file) and by `aspod sim --foxglove` (the same live, over
Foxglove's WebSocket protocol). Both go through the `foxglove-sdk` package (the `foxglove` extra): its channels
belong to one `foxglove.Context`, and a sink on that context (an MCAP writer, a WebSocket server) takes them.

Topics (times: the frame's, in nanoseconds since the Unix epoch; a capture's on a world's clock from the second it
began, its if_tsoffset):

* `/joints` (JSON, `aspod.JointStates`): per axis its name, position and velocity in SI units as Foxglove's joint
  states have them (radians; the gripper's opening in metres), the same in the units the console shows (degrees,
  millimetres), its motor current (A) and mode; from TelemetryJoints.
* `/arm` (`foxglove.SceneUpdate`): the arm as a 3D scene, in the frame `world` (origin on the central shaft's axis
  at the foot of link I, z up: hil_sim/arm.py `gripper_position_m`): its links as a line through the foot of link I,
  J1, the elbow, the wrist and the tip, a sphere at each; from TelemetryJoints, by the arm's forward kinematics.
* `/tf` (`foxglove.FrameTransforms`): the frames `j1`, `elbow`, `wrist` and `tip` in `world`, turned with the mount.
* `/tracker` (JSON, `aspod.TrackerPointing`): the sun from the controller's ephemeris, each axis's angle and its
  pointing error (degrees), the photocells; from TelemetryTracker.
* `/status` (JSON, `aspod.Status`): the controller's state and faults by name, supply, temperature, real-time
  factor; from TelemetryStatus.
* `/log` (`foxglove.Log`): every event (MotionDone, StateChanged, FaultReport, TimingWarning, ...) as a line, as
  `aspod log` shows it; a fault is an error, a warning a warning; a frame that failed to decode a warning.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

from protocol.schema import Direction, MsgClass
from protocol.states import ARM_AXES, Axis, AxisMode, ControllerState, Fault
from host_tools.outputs import Kind, begins
from host_tools.sessions.decode import MAC_BAD, DecodedFrame, SessionDecoder, message_text
from host_tools.sessions.segments import SegmentCutter

if TYPE_CHECKING:
    import foxglove

# An MCAP file begins with its magic: 0x89, "MCAP", the format's major version '0', "\r\n" (mcap.dev/spec).
MCAP = Kind("an MCAP file", begins(b"\x89MCAP0\r\n"), (".mcap",))
MODULES = ("foxglove",)             # what the `foxglove` extra installs that this module needs
DEFAULT_PORT = 8765                 # Foxglove's own default for its WebSocket connection
WORLD_FRAME = "world"
CHAIN = ("j1", "elbow", "wrist", "tip")

_ANGLE_SCHEMA = {"type": "number"}
JOINTS_SCHEMA = {
    "title": "aspod.JointStates", "type": "object",
    "description": "The arm's axes as TelemetryJoints reports them (j1, j2, j3, j4, gripper, mount)",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "name": {"type": "array", "items": {"type": "string"}},
        "position": {"type": "array", "items": _ANGLE_SCHEMA, "description": "rad (gripper: opening, m)"},
        "velocity": {"type": "array", "items": _ANGLE_SCHEMA, "description": "rad/s (gripper: m/s)"},
        "position_deg": {"type": "array", "items": _ANGLE_SCHEMA, "description": "deg (gripper: opening, mm)"},
        "velocity_deg_s": {"type": "array", "items": _ANGLE_SCHEMA, "description": "deg/s (gripper: mm/s)"},
        "current_a": {"type": "array", "items": _ANGLE_SCHEMA, "description": "motor current, A"},
        "mode": {"type": "array", "items": {"type": "string"}},
        "homed": {"type": "array", "items": {"type": "boolean"}},
    },
}
TRACKER_SCHEMA = {
    "title": "aspod.TrackerPointing", "type": "object",
    "description": "The solar tracker's pointing as TelemetryTracker reports it; angles in degrees",
    "properties": {name: {"type": "number"} for name in (
        "sun_az", "sun_el", "angle_az", "angle_el", "error_az", "error_el", "cell_diff_az", "cell_diff_el",
        "cell_sum_az", "cell_sum_el", "duty_az", "duty_el")} | {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}},
}
STATUS_SCHEMA = {
    "title": "aspod.Status", "type": "object",
    "description": "The controller's state as TelemetryStatus reports it",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "state": {"type": "string"}, "faults": {"type": "string"}, "supply_v": {"type": "number"},
        "temp_c": {"type": "number"}, "rtf_recent": {"type": "number"}, "lag_ms": {"type": "number"},
        "link_errors": {"type": "integer"},
    },
}
TRACKER_FIELDS = tuple(name for name in TRACKER_SCHEMA["properties"] if name != "timestamp")
TOPICS = ("/joints", "/arm", "/tf", "/tracker", "/status", "/log")


def require_foxglove(what: str) -> None:
    """MissingExtra (exit 2) naming the `foxglove` extra when foxglove-sdk is not installed."""
    from kernels.extras import require
    require("foxglove", *MODULES, what=what)


def _timestamp(time_ns: int) -> dict:
    return {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000}


def _name(kind, value: int) -> str:
    try:
        return kind(value).name or "NONE"
    except ValueError:
        return str(value)


class FoxgloveTopics:
    """The topics above on one `foxglove.Context`: `add(decoded, time_ns)` logs what a frame maps to, to every sink
    of the context (an MCAP writer, a WebSocket server). `counts`: messages logged per topic."""

    def __init__(self, context: "foxglove.Context") -> None:
        import foxglove
        from foxglove import channels
        self.context = context
        self.joints = foxglove.Channel("/joints", schema=JOINTS_SCHEMA, context=context)
        self.scene = channels.SceneUpdateChannel("/arm", context=context)
        self.frames = channels.FrameTransformsChannel("/tf", context=context)
        self.tracker = foxglove.Channel("/tracker", schema=TRACKER_SCHEMA, context=context)
        self.status = foxglove.Channel("/status", schema=STATUS_SCHEMA, context=context)
        self.log = channels.LogChannel("/log", context=context)
        self.counts = dict.fromkeys(TOPICS, 0)

    def add(self, d: DecodedFrame, time_ns: int) -> None:
        """Log what `d`, seen at `time_ns`, says to Foxglove: telemetry and events from the controller, and frames
        that failed to decode or verify. Commands and replies are not shown."""
        if d.direction is not Direction.TO_HOST:
            return
        if d.message is None or d.mac == MAC_BAD:
            self._log_line(time_ns, "Warning", f"{d.link}: {d.name}: {d.error or 'MAC does not verify'}")
            return
        name, values = d.name, d.fields()
        if name == "TelemetryJoints":
            self._joints(values, time_ns)
        elif name == "TelemetryTracker":
            self._count(self.tracker, "/tracker", {"timestamp": _timestamp(time_ns)}
                        | {f: float(values[f]) for f in TRACKER_FIELDS}, time_ns)
        elif name == "TelemetryStatus":
            self._count(self.status, "/status", {
                "timestamp": _timestamp(time_ns), "state": _name(ControllerState, values["state"]),
                "faults": _name(Fault, values["faults"]), "supply_v": float(values["supply_v"]),
                "temp_c": float(values["temp_c"]), "rtf_recent": float(values["rtf_recent"]),
                "lag_ms": float(values["lag_ms"]), "link_errors": int(values["link_errors"])}, time_ns)
        elif d.frame.cls == MsgClass.EVENT:
            self._log_line(time_ns, self._level(name, values), message_text(d))

    @staticmethod
    def _level(name: str, values: dict) -> str:
        if name == "FaultReport" or (name == "StateChanged" and values["state"] == ControllerState.FAULT):
            return "Error"
        if name in ("TimingWarning", "TemperatureWarning") and values["active"]:
            return "Warning"
        if name == "MotionDone" and values["reason"] != 0:
            return "Warning"
        return "Info"

    def _log_line(self, time_ns: int, level: str, text: str) -> None:
        from foxglove.messages import Log, LogLevel, Timestamp
        stamp = Timestamp(time_ns // 1_000_000_000, time_ns % 1_000_000_000)
        self.log.log(Log(timestamp=stamp, level=getattr(LogLevel, level), message=text, name="aspod"),
                     log_time=time_ns)
        self.counts["/log"] += 1

    def _count(self, channel, topic: str, message, time_ns: int) -> None:
        channel.log(message, log_time=time_ns)
        self.counts[topic] += 1

    def _joints(self, values: dict, time_ns: int) -> None:
        names = [a.name.lower() for a in ARM_AXES]
        shown = [float(values[f"{n}_pos"]) for n in names]
        rates = [float(values[f"{n}_vel"]) for n in names]
        gripper = ARM_AXES.index(Axis.GRIPPER)
        si = [v * 1e-3 if k == gripper else math.radians(v) for k, v in enumerate(shown)]
        si_rates = [v * 1e-3 if k == gripper else math.radians(v) for k, v in enumerate(rates)]
        self._count(self.joints, "/joints", {
            "timestamp": _timestamp(time_ns), "name": names, "position": si, "velocity": si_rates,
            "position_deg": shown, "velocity_deg_s": rates,
            "current_a": [float(values[f"{n}_current"]) for n in names],
            "mode": [_name(AxisMode, values[f"{n}_mode"]) for n in names],
            "homed": [bool(values["homed"] >> k & 1) for k in range(len(names))]}, time_ns)
        self._arm(dict(zip(names, si)), time_ns)

    def _arm(self, angles: dict[str, float], time_ns: int) -> None:
        """The arm's links placed by its forward kinematics (hil_sim/arm.py `chain_points_m`)."""
        from foxglove.messages import (Color, FrameTransform, FrameTransforms, LinePrimitive, LinePrimitiveLineType,
                                       Point3, Pose, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive,
                                       Timestamp, Vector3)
        from hil_sim.arm import chain_points_m
        from hil_sim.arm_params import ARM_PLANT_PARAMS
        phi = angles["mount"]
        points = chain_points_m(angles["j1"], angles["j2"], angles["j3"], phi)
        mount = ARM_PLANT_PARAMS.mount.base_radius_m
        foot = (mount * math.cos(phi), mount * math.sin(phi), 0.0)
        chain = [foot] + [tuple(float(v) for v in points[name]) for name in CHAIN]
        stamp = Timestamp(time_ns // 1_000_000_000, time_ns % 1_000_000_000)
        turn = Quaternion(x=0.0, y=0.0, z=math.sin(phi / 2), w=math.cos(phi / 2))
        link_color, joint_color = Color(r=0.85, g=0.55, b=0.1, a=1.0), Color(r=0.2, g=0.4, b=0.9, a=1.0)
        entity = SceneEntity(
            timestamp=stamp, frame_id=WORLD_FRAME, id="arm", frame_locked=False,
            lines=[LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=0.02, scale_invariant=False,
                                 points=[Point3(x=x, y=y, z=z) for x, y, z in chain], color=link_color)],
            spheres=[SpherePrimitive(pose=Pose(position=Vector3(x=x, y=y, z=z), orientation=turn),
                                     size=Vector3(x=0.04, y=0.04, z=0.04), color=joint_color) for x, y, z in chain])
        self._count(self.scene, "/arm", SceneUpdate(entities=[entity]), time_ns)
        transforms = [FrameTransform(timestamp=stamp, parent_frame_id=WORLD_FRAME, child_frame_id=name,
                                     translation=Vector3(x=x, y=y, z=z), rotation=turn)
                      for name, (x, y, z) in zip(CHAIN, chain[1:])]
        self._count(self.frames, "/tf", FrameTransforms(transforms=transforms), time_ns)


def time_ns(started_s: int, time_s: float) -> int:
    """A frame's time in nanoseconds since the Unix epoch: `time_s` on its clock after the whole second `started_s`
    (a capture's if_tsoffset; 0 for one on the wall clock), added as integers so no nanosecond is lost to rounding."""
    return started_s * 1_000_000_000 + round(time_s * 1e9)


class FoxgloveTap:
    """The controller's line, live, to Foxglove: a `RecordedPort`'s capture (host_tools/worlds/ports.py) that cuts
    what the controller writes into frames, decodes them and logs them (`FoxgloveTopics`), stamped with the world's
    time from `started_s` (the wall-clock second the world began). What the controller reads is not looked at."""

    def __init__(self, topics: FoxgloveTopics, started_s: int, on_close=None) -> None:
        self.topics = topics
        self.started_s = started_s
        self._cutter = SegmentCutter()
        self._decoder = SessionDecoder()
        self._on_close = on_close

    def write(self, link: str, direction: Direction, data: bytes, time_s: float) -> None:
        if direction is not Direction.TO_HOST:
            return
        for segment, length in self._cutter.feed(data):
            d = self._decoder.decode(segment, time_s, link, direction, length)
            self.topics.add(d, time_ns(self.started_s, time_s))

    def close(self) -> None:
        if self._on_close is not None:
            self._on_close()
            self._on_close = None


def serve(port: int, host: str = "127.0.0.1", name: str = "aspod sim") -> tuple[FoxgloveTopics, "foxglove.WebSocketServer"]:
    """A Foxglove WebSocket server on `host`:`port` (0: any free port; its `port` says which) and the topics it
    serves; OSError if the port cannot be had. Stop it with `server.stop()`."""
    import foxglove
    context = foxglove.Context()
    topics = FoxgloveTopics(context)
    try:
        server = foxglove.start_server(name=name, host=host, port=port, context=context)
    except RuntimeError as exc:            # the SDK says a bind failure so
        raise OSError(f"cannot serve Foxglove's WebSocket on {host}:{port}: {exc}") from None
    return topics, server


__all__ = ["DEFAULT_PORT", "FoxgloveTap", "FoxgloveTopics", "MCAP", "TOPICS", "require_foxglove", "serve",
           "time_ns"]
