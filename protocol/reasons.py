"""Reason codes: why a frame, command or state change was refused, with the remedy.

One table, used by the controller's answers, the host's errors, the generated
docs/protocol.md and teleop's messages. A code is one byte on the wire.
"""
from __future__ import annotations

import enum


class Reason(enum.IntEnum):
    OK = 0
    BAD_CRC = 1
    BAD_FRAME = 2
    UNSUPPORTED_VERSION = 3
    UNSUPPORTED_FLAGS = 4
    UNAUTHENTICATED = 5
    BAD_MAC = 6
    REPLAY = 7
    NO_SESSION = 8
    SCHEMA_MISMATCH = 9
    UNKNOWN_MESSAGE = 10
    WRONG_DIRECTION = 11
    BAD_LENGTH = 12
    OUT_OF_RANGE = 13
    SEQUENCE_GAP = 14
    NOT_ALLOWED_IN_STATE = 15
    LINK_SUSPENDED = 16
    LINK_TIMEOUT = 17
    ESTOP = 18
    FAULT_LATCHED = 19
    SESSION_RESET = 20
    HAL_STALE = 21
    SUPPLY_LOW = 22
    OVER_TEMPERATURE = 23
    HOST_REQUEST = 24
    UNKNOWN_PARAM = 25
    SAVE_FAILED = 26
    NOT_HOMED = 27
    SOFT_LIMIT = 28
    BUSY = 29
    ENCODER_FAULT = 30
    STALL = 31
    FOLLOWING_ERROR = 32
    OVER_CURRENT = 33
    HOMING_FAILED = 34
    OPEN_CIRCUIT = 35
    GRIPPER_TIMEOUT = 36
    NOT_SETTLED = 37
    CANCELLED = 38
    DIAL_NOT_LOW = 39
    SWITCH_POSITION = 40
    ENCODER_STALE = 41
    CURRENT_STALE = 42
    HOST_OVERLOADED = 43
    TRAJ_FULL = 44
    TRAJ_ORDER = 45
    TRAJ_COUNT = 46
    TRAJ_ENDPOINTS = 47
    UNCOMMANDED_MOTION = 48
    SESSION_CLOSED = 49

    @property
    def doc(self) -> str:
        return _TABLE[self][0]

    @property
    def remedy(self) -> str:
        return _TABLE[self][1]

    def describe(self) -> str:
        """`NAME (n): meaning. Remedy: ...`, for error messages."""
        return f"{self.name} ({int(self)}): {self.doc}. Remedy: {self.remedy}"


def reason_name(code: int) -> str:
    """Name of a code received from the wire, also for codes this build does not know."""
    try:
        return Reason(code).name
    except ValueError:
        return f"UNKNOWN_REASON_{code}"


_TABLE: dict[Reason, tuple[str, str]] = {
    Reason.OK: ("accepted and done", "none"),
    Reason.BAD_CRC: ("the frame's CRC-32 does not match its contents (line noise)",
                     "none needed for occasional noise; check cabling, baud rate and grounding if it climbs"),
    Reason.BAD_FRAME: ("the bytes between two delimiters are not a valid COBS frame or are shorter than a header",
                       "check that both ends speak protocol v1 framing (COBS between 0x00 delimiters)"),
    Reason.UNSUPPORTED_VERSION: ("the header's protocol version is not one this end speaks",
                                 "upgrade the older end; both must speak the same major version"),
    Reason.UNSUPPORTED_FLAGS: ("a must-understand flag (bits 4-7) is set that this end does not know",
                               "clear the flag or upgrade this end"),
    Reason.UNAUTHENTICATED: ("the frame carries no MAC but this link requires one",
                             "configure the same pre-shared key on both ends (--key-file)"),
    Reason.BAD_MAC: ("the frame's HMAC-SHA256 tag does not verify under the session or handshake key",
                     "use the controller's key (--key-file) and handshake again; a forged frame is ignored"),
    Reason.REPLAY: ("the frame's 48-bit counter is not above the last one accepted (replayed or duplicated frame: "
                    "counted, never answered); in a Nak, a command older than the reply cache",
                    "none: a genuine sender never reuses a counter; handshake again after a restart"),
    Reason.NO_SESSION: ("no session is established: HELLO must come first",
                        "send HELLO (teleop does this on connect) and retry"),
    Reason.SCHEMA_MISMATCH: ("the host's message schema hash differs from the controller's",
                             "run host tools built from the same protocol declaration as the controller"),
    Reason.UNKNOWN_MESSAGE: ("the message id is not declared in this protocol version", "check the schema hash; upgrade"),
    Reason.WRONG_DIRECTION: ("the message is declared for the other direction or another class",
                             "send only host-to-controller messages in their declared class"),
    Reason.BAD_LENGTH: ("the header's length is above 240 or not the frame's size, or the payload length does not "
                        "match the message's declared fields", "check the schema hash"),
    Reason.OUT_OF_RANGE: ("a field is outside its declared range or is not a finite number, or beyond a limit the "
                          "controller sets (an axis's speed parameter, a telemetry rate the line cannot carry, say), "
                          "or not meaningful for that axis",
                          "see the message's field table in docs/protocol.md and the axis's parameters (`params`)"),
    Reason.SEQUENCE_GAP: ("a command's (or an event's) sequence number skips ahead of the next expected one",
                          "none: the host retransmits from the expected sequence (go-back-N)"),
    Reason.NOT_ALLOWED_IN_STATE: ("the command is not allowed in the controller's present state",
                                  "check `status`; e.g. reset after a fault or e-stop before enabling"),
    Reason.LINK_SUSPENDED: ("the host gave up after its retry limit; the command's outcome is unknown",
                            "check the link, then reconnect (handshake) and query status before retrying"),
    Reason.LINK_TIMEOUT: ("no valid frame arrived within the link timeout; the controller went to its safe state",
                          "restore the link, then send reset"),
    Reason.ESTOP: ("an emergency stop is latched", "clear the cause, then send reset"),
    Reason.FAULT_LATCHED: ("a fault is latched and the controller is in its safe state",
                           "read `status` for the fault bits, clear the cause, then send reset"),
    Reason.SESSION_RESET: ("the session was replaced before the command was answered; its outcome is unknown",
                           "query status before retrying"),
    Reason.HAL_STALE: ("the hardware bus (HAL) inputs stopped arriving: the analog inputs are older than hal_stale_s, "
                       "or in lock-step the plant's tick has not come for lockstep_wait_s",
                       "check the plant or CAN bus (FaultReport says what was how old), then reset"),
    Reason.SUPPLY_LOW: ("the supply voltage fell below its limit", "restore the supply, then reset"),
    Reason.OVER_TEMPERATURE: ("the controller temperature left its allowed range",
                              "let the controller cool (or warm) into range, then reset"),
    Reason.HOST_REQUEST: ("the host asked for it", "none"),
    Reason.UNKNOWN_PARAM: ("no parameter has that name", "list them with `params` (teleop) / ParamList"),
    Reason.SAVE_FAILED: ("the parameters could not be written to their file (the previous file is intact)",
                         "check the --params path, its directory and free space, then save again"),
    Reason.NOT_HOMED: ("absolute moves need a homed axis", "home it first (`home j1`, or `home all`); "
                       "relative moves and jogs are allowed before homing"),
    Reason.SOFT_LIMIT: ("the target lies beyond the joint's soft limit, or a motion stopped at it",
                        "choose a target inside the limits (parameters <axis>_min_deg and <axis>_max_deg)"),
    Reason.BUSY: ("the axis is homing; for a trajectory, a joint is not holding still (another motion runs), or a "
                  "trajectory is running and its knots cannot change; for a joint's speed or acceleration "
                  "parameter, the joint is in a motion planned with it", "wait for it to finish, or `stop` it first"),
    Reason.ENCODER_FAULT: ("an encoder count jumped further than its joint can move",
                           "check the encoder, reset, then home again"),
    Reason.STALL: ("a joint was driven hard but did not move", "clear the jam or the brake, then reset"),
    Reason.FOLLOWING_ERROR: ("a joint fell too far behind its setpoint", "check encoder and load, then reset"),
    Reason.OVER_CURRENT: ("a motor current stayed above its trip level", "check the motor for a short, then reset"),
    Reason.HOMING_FAILED: ("no home switch was found within the axis's maximum homing travel",
                           "check the home switch, reset, home again"),
    Reason.OPEN_CIRCUIT: ("a motor was driven but drew no current", "check the motor circuit, then reset"),
    Reason.GRIPPER_TIMEOUT: ("the gripper reached neither its end switch nor a grip in time",
                             "check the gripper's switches and motor, then reset"),
    Reason.NOT_SETTLED: ("the motion's profile ended but the joint did not settle within its tolerance in time",
                         "check the load and the gains; the joint holds where it is"),
    Reason.CANCELLED: ("the motion was cancelled by disable, e-stop or the safe state",
                       "see the controller's state; enable and command it again"),
    Reason.DIAL_NOT_LOW: ("the control box's speed dial is above its low setting (parameter trk_dial_low_pct): the "
                          "report's operating instructions forbid starting (speed switch on, or main power on with "
                          "the speed switch on), changing the control mode or changing direction with the dial high",
                          "turn the dial low first (`dial 0`), repeat the switch, then turn the dial up"),
    Reason.SWITCH_POSITION: ("that switch has no such position (main and sensor: off, on; mode: manual, sensor; "
                             "direction: cw, ccw; speed: brake, on)",
                             "use one of the switch's own positions, e.g. `switch speed brake`"),
    Reason.ENCODER_STALE: ("an axis had no new encoder count for longer than encoder_stale_s",
                           "check the encoder and the HAL bus (FaultReport gives the age); on a slow host raise "
                           "encoder_stale_s; then reset"),
    Reason.CURRENT_STALE: ("an axis had no current reading for longer than current_stale_s while driving",
                           "check the current sense and the HAL bus (FaultReport gives the age); on a slow host "
                           "raise current_stale_s; then reset"),
    Reason.HOST_OVERLOADED: ("the controller's motor loop ran later than loop_late_max_s on the wall clock: the "
                             "computer running the emulator is overloaded, the hardware is not at fault",
                             "reduce the load on the host, or raise loop_late_max_s, then reset"),
    Reason.TRAJ_FULL: ("the controller's trajectory buffer already holds as many knots as it can (TrajState "
                       "capacity)", "send a shorter trajectory (fewer knots), or split the motion into trajectories"),
    Reason.TRAJ_ORDER: ("a trajectory knot out of order: its index is not the next one (TrajState knots), the first "
                        "is not at t = 0, or its time is not strictly after the previous knot's",
                        "send the knots in order from index 0 at t = 0, times increasing; TrajClear to start over"),
    Reason.TRAJ_COUNT: ("TrajRun's count is not the number of knots the controller holds, or fewer than 2 are held "
                        "(a knot lost or sent twice)", "TrajClear and upload the knots again"),
    Reason.TRAJ_ENDPOINTS: ("a trajectory must start where each joint holds (within 0.1 deg) at rest and end at "
                            "rest: a first or last knot's speed above 0.01 deg/s, or a first position away from "
                            "the joint's", "plan from the joints' present positions, starting and ending at rest"),
    Reason.UNCOMMANDED_MOTION: ("a joint or tracker axis moved, or a motor drew current, with the controller's "
                                "outputs off; or another node sent the controller's own frames on the HAL bus",
                                "find what drives it (the HAL bus, a driver, a brake), then reset once it is still"),
    Reason.SESSION_CLOSED: ("the host closed its session (Close): the controller stopped every motion and went to "
                            "its safe state without a fault, IDLE; a frame of the closed session is refused",
                            "none for a close; to go on, open a new session (Hello; teleop: `connect`)"),
}

assert set(_TABLE) == set(Reason), "every reason needs a doc and a remedy"
