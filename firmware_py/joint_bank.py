"""The joints' hot state in flat rows of numbers, and the `Axis` objects as its facade.

A `JointBank` holds, for each joint, the numbers `joints_tick` (firmware_py/joints_tick.py, a
joint's tick, written once) reads and writes, one row per joint in each of its groups.
`BankedAxis` is an `Axis` whose hot attributes live in the bank: each is a descriptor onto its
joint's row, so the commands, modes, faults and homing of `Axis` work on the very numbers the
tick uses; no state is copied per tick. `BankedEstimator` and `BankedDebounce` do the same for
the estimator and the debounced fault checks.

`JointBank.run` is one tick of a span of joints: `joints_tick` for as many as it can take, and
`BankedAxis.act` for each joint it hands over (rare: faults, a move's end, a soft limit, homing's
phases, a trajectory's curve), after which the kernel goes on with that joint's tick where it
stopped. `run_arm` is the arm's first call of a tick: the gravity feed-forward and as many joints
as `arm_joints_tick` takes, usually all of them, in one call; `run` goes on from a joint handed
over. `BankedAxis.update` is one joint's tick on inputs given to it (`single_axis` builds a joint
alone on a bank of its own, for tests and rigs).

The rows are Python lists, or with `compiled=True` numpy arrays for the functions compiled by numba
(firmware_py/joints_compiled.py); a tick's inputs then go to them as tuples (`take_inputs`), and the
duties come out of an array (`duty_list`) once the tick is done.
"""
from __future__ import annotations

from typing import Any, Callable, Optional, Sequence

import numpy as np

from protocol.states import AxisMode

from firmware_py import joints_tick as jt
from firmware_py.axis import Axis, AxisConfig, AxisError, Debounce
from firmware_py.estimator import EstimatorConfig, SteadyStateEstimator
from firmware_py.homing import Homing
from firmware_py.joints_compiled import compiled_arm_joints_tick, compiled_joints_tick
from firmware_py.hermite import HermiteProfile
from firmware_py.profiles import Profile

_MODES = tuple(AxisMode)
assert all(int(mode) == k for k, mode in enumerate(_MODES))


class JointBank:
    """The hot state of `size` joints wired to `channels` HAL channels: per group (`state`, `int_state`, `config`,
    `int_config`, `profile`) one row of numbers per joint, the columns named in firmware_py/joints_tick.py;
    `axes[k]` is joint k's facade. `compiled`: numpy rows and the tick compiled by numba."""

    def __init__(self, size: int, channels: int, compiled: bool = False, masses: Sequence[float] = ()) -> None:
        self.size = size
        self.compiled = compiled
        self._tick = compiled_joints_tick() if compiled else jt.joints_tick
        self._arm_tick = compiled_arm_joints_tick() if compiled else jt.arm_joints_tick
        rows = _arrays if compiled else _lists
        self.state = rows(size, jt.STATE_COLUMNS, float)
        for row in self.state:
            for column in (jt.COUNT_S, jt.SETTLE_SINCE_S, jt.STALL_SINCE_S, jt.TRIP_SINCE_S, jt.OPEN_SINCE_S):
                row[column] = jt.NONE
        self.int_state = rows(size, jt.INT_STATE_COLUMNS, int)
        self.config = rows(size, jt.CONFIG_COLUMNS, float)
        self.int_config = rows(size, jt.INT_CONFIG_COLUMNS, int)
        self.profile = rows(size, jt.PROFILE_COLUMNS, float)
        # the objects behind the profile rows
        self.profiles: list[Optional[Profile | HermiteProfile]] = [None] * size
        self.axes: list[BankedAxis] = []
        self.channels: list[int] = []       # each joint's HAL channel
        self.handed_back = 0                # events `joints_tick` handed to the facade (`BankedAxis.act`)
        # the arm's mass model (MassModel.row), for `run_arm`'s gravity feed-forward: constant, so a tuple (which
        # numba takes for less than an array)
        self.masses = tuple(masses) + (0.0,) * (jt.MASS_COLUMNS - len(masses))
        # each joint's gravity torque (given to `take_inputs`, or computed by `run_arm`) and its duty at its channel
        self.gravity_nm = rows(1, size, float)[0]
        self.duties = rows(1, channels, float)[0]
        # this tick's inputs (take_inputs), as the tick function takes them
        self._taken: tuple = ()

    def take_inputs(self, count_s: float, current_s: float, counts: Sequence[int], currents_a: Sequence[float],
                    home: Sequence[bool], gravity_nm: Optional[Sequence[float]] = None) -> None:
        """This tick's inputs for its runs, per channel: the counts (arrived at `count_s`, NaN: none), the currents
        (arrived at `current_s`, NaN: none) and the home switches; `gravity_nm[k]`, joint k's gravity torque if it
        has one (None: `run_arm` computes them)."""
        if gravity_nm is not None:
            self.gravity_nm[:len(gravity_nm)] = gravity_nm
        if self.compiled:                   # numba takes a tuple of numbers for less than filling an array costs
            counts, currents_a, home = tuple(counts), tuple(currents_a), tuple(home)
        self._taken = (count_s, current_s, counts, currents_a, home, self.gravity_nm)

    def run_arm(self, stop: int, now: float, gravity_m_s2: float, payload_kg: float) -> int:
        """The arm's first call of a tick (`arm_joints_tick`): the gravity torques of J1..J3 for the whole tick (from
        the mass model, `gravity_m_s2` and the payload), then joints 0 .. `stop - 1` as far as the kernel takes them;
        returns the first joint it hands over (`stop`: none). `run` goes on from there."""
        count_s, current_s, counts, currents_a, home, gravity_nm = self._taken
        return self._arm_tick(stop, now, count_s, current_s, gravity_m_s2, payload_kg, self.masses, counts,
                              currents_a, home, gravity_nm, self.duties, self.state, self.int_state, self.config,
                              self.int_config, self.profile)

    def run(self, first: int, stop: int, now: float) -> None:
        """One tick of joints `first` .. `stop - 1`, in order, on the inputs taken (`first` may be a joint the last
        call handed over); each joint's duty into `duties` at its channel."""
        k = first
        while k < stop:
            if self.int_state[k][jt.EVENT] != jt.EV_NONE:      # handed over: the facade acts on it
                self.handed_back += 1
                if not self.axes[k].act(now):
                    self.duties[self.channels[k]] = 0.0        # the tick ended there (a fault): duty 0
                    k += 1
                    continue
            k = self._tick(k, stop, now, *self._taken, self.duties, self.state, self.int_state, self.config,
                           self.int_config, self.profile)

    def duty_list(self) -> list[float]:
        """This tick's duties by channel, a list of the caller's (a channel without a joint: 0.0)."""
        return self.duties.tolist() if self.compiled else list(self.duties)

    def load_profile(self, k: int, profile: Optional[Profile | HermiteProfile]) -> None:
        """Joint k follows `profile` (None: none): its end and segments into k's profile row; a profile that is not
        constant-acceleration segments (a trajectory's curve) is marked for the facade to sample."""
        self.profiles[k] = profile
        if profile is None:
            self.int_state[k][jt.PROFILE_SEGMENTS] = 0
            return
        row = self.profile[k]
        row[jt.DURATION_S], row[jt.END_POS_RAD], row[jt.END_VEL_RAD_S] = (
            profile.duration_s, profile.end_pos_rad, profile.end_vel_rad_s)
        if not profile.constant_acceleration:
            self.int_state[k][jt.PROFILE_SEGMENTS] = jt.FACADE_PROFILE
            return
        segments = profile.segments
        if len(segments) > jt.MAX_SEGMENTS:
            raise ValueError(f"a profile of {len(segments)} segments; the joints' tick holds {jt.MAX_SEGMENTS}")
        for j, segment in enumerate(segments):
            start = jt.SEGMENTS + jt.SEGMENT_COLUMNS * j
            row[start:start + jt.SEGMENT_COLUMNS] = segment
        self.int_state[k][jt.PROFILE_SEGMENTS] = len(segments)


def _lists(size: int, columns: int, kind: type) -> list[list]:
    return [[kind()] * columns for _ in range(size)]


def _arrays(size: int, columns: int, kind: type) -> np.ndarray:
    return np.zeros((size, columns), np.int64 if kind is int else np.float64)


# ---- descriptors: an attribute of a banked object is a number in its joint's row
STATE, INT_STATE, CONFIG, INT_CONFIG = range(4)     # a banked object's `_rows`, its joint's row of each group


class _Banked:
    """An object whose attributes (the descriptors below) live in joint `row` of `bank`."""

    def _bank_rows(self, bank: JointBank, row: int) -> None:
        self._bank, self._row = bank, row
        self._rows = (bank.state[row], bank.int_state[row], bank.config[row], bank.int_config[row])


class _Float:
    """The attribute is float column `column` of the object's row in group `group` (STATE ... INT_CONFIG)."""

    def __init__(self, group: int, column: int) -> None:
        self.group, self.column = group, column

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return float(obj._rows[self.group][self.column])

    def __set__(self, obj, value: float) -> None:
        obj._rows[self.group][self.column] = float(value)


class _Int(_Float):
    """An int column (`kind` turns it into the attribute's type: int, bool, AxisMode)."""

    def __init__(self, group: int, column: int, kind: Callable[[int], Any] = int) -> None:
        super().__init__(group, column)
        self.kind = kind

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return self.kind(obj._rows[self.group][self.column])

    def __set__(self, obj, value: int) -> None:
        obj._rows[self.group][self.column] = int(value)


class _OptionalTime(_Float):
    """A time that may be None, kept as NaN."""

    def __init__(self, column: int) -> None:
        super().__init__(STATE, column)

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        value = obj._rows[STATE][self.column]
        return None if value != value else float(value)

    def __set__(self, obj, value: Optional[float]) -> None:
        obj._rows[STATE][self.column] = jt.NONE if value is None else float(value)


class _LastCount:
    """The raw count of the last accepted sample, or None: a has-count flag and the count."""

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        row = obj._rows[INT_STATE]
        return int(row[jt.LAST_COUNT]) if row[jt.HAS_COUNT] else None

    def __set__(self, obj, value: Optional[int]) -> None:
        row = obj._rows[INT_STATE]
        row[jt.HAS_COUNT], row[jt.LAST_COUNT] = (0, 0) if value is None else (1, int(value))


class _Profile:
    """The motion profile: the object for the facade, its segments in the profile row for the tick."""

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return obj._bank.profiles[obj._row]

    def __set__(self, obj, value: Optional[Profile | HermiteProfile]) -> None:
        obj._bank.load_profile(obj._row, value)


# ---- the banked objects
class BankedEstimator(_Banked, SteadyStateEstimator):
    """A `SteadyStateEstimator` whose state and constants live in joint `row` of `bank`."""

    pos_rad = _Float(STATE, jt.POS_RAD)
    vel_rad_s = _Float(STATE, jt.VEL_RAD_S)
    offset_rad = _Float(STATE, jt.OFFSET_RAD)
    last_count = _LastCount()
    turns_counts = _Int(INT_STATE, jt.TURNS_COUNTS)
    missed_ticks = _Int(INT_STATE, jt.MISSED_TICKS)
    flags = _Int(INT_STATE, jt.ESTIMATOR_FLAGS)
    _dt = _Float(CONFIG, jt.EST_DT_S)
    k_pos = _Float(CONFIG, jt.K_POS)
    k_vel = _Float(CONFIG, jt.K_VEL)
    _max_counts_per_tick = _Float(CONFIG, jt.MAX_COUNTS_PER_TICK)
    _rad_per_count = _Float(CONFIG, jt.RAD_PER_COUNT)
    _stale_ticks = _Int(INT_CONFIG, jt.STALE_TICKS)
    _margin = _Int(INT_CONFIG, jt.GLITCH_MARGIN_COUNTS)

    def __init__(self, bank: JointBank, row: int, config: EstimatorConfig, pos_rad: float = 0.0) -> None:
        self._bank_rows(bank, row)
        super().__init__(config, pos_rad)


class BankedDebounce(_Banked, Debounce):
    """A `Debounce` whose `since` lives in joint `row` of `bank`, state column `column`."""

    def __init__(self, bank: JointBank, row: int, column: int) -> None:
        self._bank_rows(bank, row)
        self._column = column
        self.since = None

    @property
    def since(self) -> Optional[float]:
        value = self._rows[STATE][self._column]
        return None if value != value else float(value)

    @since.setter
    def since(self, value: Optional[float]) -> None:
        self._rows[STATE][self._column] = jt.NONE if value is None else float(value)


class BankedHoming(_Banked, Homing):
    """`Homing` whose phase and start live in joint `row` of `bank`."""

    phase = _Int(INT_STATE, jt.HOMING_PHASE)
    start_rad = _Float(STATE, jt.HOME_START_RAD)

    def __init__(self, axis: BankedAxis, bank: JointBank, row: int) -> None:
        self._bank_rows(bank, row)
        super().__init__(axis)


class BankedAxis(_Banked, Axis):
    """An `Axis` whose hot state lives in joint `row` of `bank`, wired to HAL channel `channel`; `bank.run` ticks it
    (`joints_tick`, and `act` on what that hands over), `update` alone."""

    mode = _Int(INT_STATE, jt.MODE, _MODES.__getitem__)
    duty = _Float(STATE, jt.DUTY)
    duty_requested = _Float(STATE, jt.DUTY_REQUESTED)
    pos_sp_rad = _Float(STATE, jt.POS_SP_RAD)
    vel_sp_rad_s = _Float(STATE, jt.VEL_SP_RAD_S)
    homed = _Int(INT_STATE, jt.HOMED, bool)
    _err = _Int(INT_STATE, jt.ERR)
    _integ = _Float(STATE, jt.INTEG)
    _duty_lo = _Float(STATE, jt.DUTY_LO)
    _duty_hi = _Float(STATE, jt.DUTY_HI)
    _count_s = _OptionalTime(jt.COUNT_S)
    _profile = _Profile()
    _profile_t0 = _Float(STATE, jt.PROFILE_T0_S)
    target_rad = _Float(STATE, jt.TARGET_RAD)
    _settle_since = _OptionalTime(jt.SETTLE_SINCE_S)
    # the hot-path copies Axis.reconfigure makes
    _dt = _Float(CONFIG, jt.DT_S)
    _kp = _Float(CONFIG, jt.KP)
    _kv = _Float(CONFIG, jt.KV)
    _ki = _Float(CONFIG, jt.KI)
    _aw = _Float(CONFIG, jt.AW)
    _vcmd_max = _Float(CONFIG, jt.VCMD_MAX)
    _relax = _Float(CONFIG, jt.RELAX)
    _lo_rad = _Float(CONFIG, jt.SOFT_MIN_RAD)
    _hi_rad = _Float(CONFIG, jt.SOFT_MAX_RAD)

    def __init__(self, bank: JointBank, row: int, channel: int, config: AxisConfig,
                 gravity_nm: Optional[Callable[[float], float]] = None,
                 on_fault: Callable[[AxisError, float], None] = lambda bits, now: None) -> None:
        if row != len(bank.axes):
            raise ValueError(f"joint rows are taken in order: row {row} while {len(bank.axes)} are built")
        self._bank_rows(bank, row)
        bank.axes.append(self)
        bank.channels.append(channel)
        bank.int_config[row][jt.CHANNEL] = channel
        super().__init__(config, gravity_nm=gravity_nm, on_fault=on_fault,
                         estimator=BankedEstimator(bank, row, config.estimator))
        self._stall = BankedDebounce(bank, row, jt.STALL_SINCE_S)
        self._trip = BankedDebounce(bank, row, jt.TRIP_SINCE_S)
        self._open = BankedDebounce(bank, row, jt.OPEN_SINCE_S)
        self._homing = BankedHoming(self, bank, row)

    def reconfigure(self, config: AxisConfig) -> None:
        super().reconfigure(config)
        row, c = self._rows[CONFIG], config
        (row[jt.FOLLOWING_ERROR_RAD], row[jt.FF_VEL], row[jt.FF_ACC], row[jt.FF_TORQUE], row[jt.I_LIMIT_A],
         row[jt.I_LIMIT_GAIN], row[jt.CURRENT_STALE_S], row[jt.I_TRIP_A], row[jt.I_TRIP_S], row[jt.STALL_DUTY],
         row[jt.STALL_VEL_RAD_S], row[jt.STALL_TIME_S], row[jt.OPEN_DUTY], row[jt.OPEN_A], row[jt.OPEN_S],
         row[jt.IN_POSITION_RAD], row[jt.IN_POSITION_VEL_RAD_S], row[jt.SETTLE_TIMEOUT_S], row[jt.ACC_LIMIT_RAD_S2],
         row[jt.HOME_MAX_TRAVEL_RAD]) = (
            c.following_error_rad, c.ff_vel_duty_s_rad, c.ff_acc_duty_s2_rad, c.ff_torque_duty_nm, c.i_limit_a,
            c.i_limit_gain_duty_a, c.current_stale_s, c.i_trip_a, c.i_trip_s, c.stall_duty, c.stall_vel_rad_s,
            c.stall_time_s, c.open_circuit_duty, c.open_circuit_a, c.open_circuit_s, c.in_position_rad,
            c.in_position_vel_rad_s, c.settle_timeout_s, c.acc_limit_rad_s2, c.home_max_travel_rad)
        flags = self._rows[INT_CONFIG]
        flags[jt.HAS_GRAVITY] = int(self._gravity_nm is not None)
        flags[jt.MOVES_NEED_HOME] = int(c.moves_need_home)

    def update(self, now: float, count: Optional[int], count_s: Optional[float], i_a: float, i_s: Optional[float],
               home_switch: bool = False) -> float:
        """Run this joint's tick on these inputs and their arrival times (None: none arrived); return the duty to
        send. The gravity torque, if the axis has one, is `gravity_nm` at the position estimated before the tick
        (as the arm's are: `JointBank.run_arm`)."""
        bank, k = self._bank, self._row
        channel = bank.channels[k]
        width = len(bank.duties)
        counts, currents, home = [0] * width, [0.0] * width, [False] * width
        counts[channel], currents[channel], home[channel] = 0 if count is None else count, i_a, bool(home_switch)
        gravity = None
        if self._gravity_nm is not None:
            gravity = list(bank.gravity_nm)
            gravity[k] = self._gravity_nm(self.estimator.pos_rad)
        bank.take_inputs(jt.NONE if count_s is None else count_s, jt.NONE if i_s is None else i_s, counts, currents,
                         home, gravity)
        bank.run(k, k + 1, now)
        return float(bank.duties[channel])

    def act(self, now: float) -> bool:
        """Act on what `joints_tick` handed over (its EVENT): a fault's bits (the tick ends, duty 0: False), a
        trajectory's curve to sample, or the supervision's decision (`Axis._act_on`); then True, the setpoint and
        the point to go on from in the row, for the kernel to finish the tick."""
        ints, floats = self._rows[INT_STATE], self._rows[STATE]
        event = int(ints[jt.EVENT])
        ints[jt.EVENT] = jt.EV_NONE
        if event == jt.EV_FAULT:
            bits = int(ints[jt.RAISED])
            if bits & jt.ENCODER_GLITCH:
                self.estimator.glitches += 1
            self._fault(bits, now)
            return False
        if event == jt.EV_SETPOINT:
            setpoint = self._profile.sample(now - self._profile_t0)
            entry = jt.SUPERVISE
        else:
            setpoint = self._act_on(int(ints[jt.MOTION]), now, float(floats[jt.TICK_POS_SP]),
                                    float(floats[jt.TICK_VEL_SP]), float(floats[jt.TICK_ACC_SP]))
            if setpoint is None:
                return False
            entry = jt.CONTROL
        floats[jt.TICK_POS_SP], floats[jt.TICK_VEL_SP], floats[jt.TICK_ACC_SP] = setpoint
        ints[jt.ENTRY] = entry
        return True


def single_axis(config: AxisConfig, gravity_nm: Optional[Callable[[float], float]] = None,
                on_fault: Callable[[AxisError, float], None] = lambda bits, now: None,
                compiled: bool = False) -> BankedAxis:
    """One joint alone, on a bank of its own (one row, HAL channel 0): `update` ticks it."""
    return BankedAxis(JointBank(1, 1, compiled), 0, 0, config, gravity_nm=gravity_nm, on_fault=on_fault)
