"""The joints' hot path: one function per tick over flat per-joint rows of numbers.

`joints_tick` does, for joints `first` .. `stop - 1` in that order, what `Axis.update`
(firmware_py/axis.py) does on an ordinary tick: the estimator, the setpoint, the cascaded control,
the current limit, the saturation, the anti-windup and the debounce checks, with the very same
floating-point operations in the same order, so the duties and the state are the same to the bit.
It reads and writes nothing but numbers in sequences indexed by joint (lists, or numpy arrays of the
same shape): no objects, enums or callables, the constants precomputed by the facade
(firmware_py/joint_bank.py), flags and modes as ints.

The contract: a joint's tick either completes here (its state written back, its duty in `duty_out`)
or leaves every number of that joint as it was and `joints_tick` returns the joint's index; the
facade then runs `Axis.update` for that joint, which does the same tick with its rare branches, and
calls `joints_tick` again from the next joint. Joints are taken strictly in order, so what one
joint's tick does to the others (a fault's safe state) happens exactly where it does in a loop of
`Axis.update` calls. A joint is handed back when its tick would

  - flag its encoder (no new count for `stale_ticks` ticks, or a count jump no motion could make),
  - be homing (the homing phases: firmware_py/homing.py),
  - follow a profile that is not constant-acceleration segments (a trajectory's cubic Hermite curve,
    firmware_py/hermite.py: its row holds no segments, PROFILE_SEGMENTS is FACADE_PROFILE),
  - be a move at or past its profile's end (settling, then the end of the move and its outcome),
  - reach a soft limit while moving or jogging (the stop),
  - exceed the following error, find the current reading stale or not a number,
  - or hold the over-current, open-circuit or stall condition long enough to fault.

Handing back more than needed is always safe (`Axis.update` gives the same answer); computing here
what `Axis.update` would do otherwise is what the tests check, to the bit (tests/test_joints_tick.py).

The law (duty is the output; gains in duty units; angles joint-side, radians; time in seconds):

  estimator (constant-velocity Kalman filter, steady-state gains k_pos, k_vel):
    pos      = pos + vel * dt                                        (predict)
    residual = turns * rad_per_count + offset - pos                  (a new count: correct)
    pos     += k_pos * residual,   vel += k_vel * residual
  setpoint: the motion profile's (pos_sp, vel_sp, acc_sp) at now - t0, or (pos_sp, 0, 0) holding
  control:
    vel_cmd  = vel_sp + kp * (pos_sp - pos),   clamped to +-vcmd_max
    u        = kv * (vel_cmd - vel) + integ + ff_vel * vel_sp + ff_acc * acc_sp [+ ff_torque * gravity_nm]
  current limit on the measured current i_a: above i_limit the upper duty bound drops below the
  last duty by i_limit_gain per A of excess (below -i_limit the lower bound rises); otherwise the
  bounds relax back toward +-1 by relax per tick
    duty     = clamp(u, duty_lo, duty_hi)
    integ   += dt * (ki * (vel_cmd - vel) + (duty - u) * aw)         (back-calculation, aw = 1 / tracking_s)
               (HOLDING within in_position of its setpoint: the ki term left out, friction holds the joint)
  debounce (a condition true at every tick since `since`, for at least its time, faults):
    over-current |i_a| > i_trip_a; open circuit |duty| >= open_duty with |i_a| < open_a;
    stall (duty != u or |u| >= stall_duty) with |vel| < stall_vel

Layout: each group is a sequence of per-joint rows, `group[k]` joint k's row, its columns named by
the constants below (in this order). `since` times and the last count's arrival time are NaN for
"none". Per-channel inputs (`counts`, `currents_a`) and the output `duty_out` are indexed by the
joint's HAL channel (`int_config` CHANNEL); `gravity_nm` by joint.
"""
from __future__ import annotations

import math

from protocol.states import AxisMode

from firmware_py import homing
from firmware_py.axis import AxisError

# state: floats that change every tick
(POS_RAD, VEL_RAD_S, OFFSET_RAD, COUNT_S, DUTY, DUTY_REQUESTED, INTEG, DUTY_LO, DUTY_HI, POS_SP_RAD, VEL_SP_RAD_S,
 TARGET_RAD, PROFILE_T0_S, SETTLE_SINCE_S, STALL_SINCE_S, TRIP_SINCE_S, OPEN_SINCE_S, HOME_START_RAD) = range(18)
STATE_COLUMNS = 18
# int_state: mode, bits and counters
(MODE, ERR, HOMED, HAS_COUNT, LAST_COUNT, TURNS_COUNTS, MISSED_TICKS, ESTIMATOR_FLAGS, PROFILE_SEGMENTS,
 HOMING_PHASE) = range(10)
INT_STATE_COLUMNS = 10
# config: floats set when the axis is configured
(EST_DT_S, K_POS, K_VEL, MAX_COUNTS_PER_TICK, RAD_PER_COUNT, DT_S, KP, KV, KI, AW, VCMD_MAX, RELAX,
 FOLLOWING_ERROR_RAD, FF_VEL, FF_ACC, FF_TORQUE, I_LIMIT_A, I_LIMIT_GAIN, CURRENT_STALE_S, I_TRIP_A, I_TRIP_S,
 STALL_DUTY, STALL_VEL_RAD_S, STALL_TIME_S, OPEN_DUTY, OPEN_A, OPEN_S, SOFT_MIN_RAD, SOFT_MAX_RAD, IN_POSITION_RAD,
 IN_POSITION_VEL_RAD_S, SETTLE_TIMEOUT_S, ACC_LIMIT_RAD_S2, HOME_MAX_TRAVEL_RAD) = range(34)
CONFIG_COLUMNS = 34
# int_config: ints set when the axis is configured
(CHANNEL, STALE_TICKS, GLITCH_MARGIN_COUNTS, HAS_GRAVITY, MOVES_NEED_HOME) = range(5)
INT_CONFIG_COLUMNS = 5
# profile: the motion profile's end, then its constant-acceleration segments (t0, pos, vel, acc) each
DURATION_S, END_POS_RAD, END_VEL_RAD_S, SEGMENTS = range(4)
SEGMENT_COLUMNS = 4
MAX_SEGMENTS = 4          # the most a profile has: stop, ramp, cruise, ramp down (firmware_py/profiles.py)
FACADE_PROFILE = -1       # PROFILE_SEGMENTS of a profile this tick does not evaluate: Axis.update follows it
PROFILE_COLUMNS = SEGMENTS + SEGMENT_COLUMNS * MAX_SEGMENTS

IDLE, MOVING, JOGGING, HOMING, HOLDING, FAULT = (int(AxisMode.IDLE), int(AxisMode.MOVING), int(AxisMode.JOGGING),
                                                 int(AxisMode.HOMING), int(AxisMode.HOLDING), int(AxisMode.FAULT))
CURRENT_LIMITED = int(AxisError.CURRENT_LIMITED)
HOME_START, HOME_CLEAR, HOME_BACKOFF = homing.START, homing.CLEAR, homing.BACKOFF    # else: seeking the switch
NONE = math.nan           # a `since` or an arrival time that is not there
# the arm's mass model for the gravity feed-forward (firmware_py/arm_config.py MassModel, its fields in this order)
(LINK2_M, LINK3_M, LINK2_KG, LINK3_KG, ELBOW_HW_KG, WRIST_FIXED_KG, WRIST_TURNED_KG, WRIST_TURNED_CG_M,
 TIP_M) = range(9)
MASS_COLUMNS = 9
GRAVITY_ROWS = 3          # the joints with gravity torque in the arm: rows 0, 1, 2 (J1, J2, J3)


def holding_torques_nm(q1: float, q2: float, q3: float, g: float, payload_kg: float, masses) -> tuple:
    """Torques J1, J2, J3 must apply to hold the pose (angles q1..q3) against gravity `g` [m/s^2]; `masses` the
    mass model's row (`MassModel.holding_torques_nm` is this function)."""
    c1 = math.cos(q1)
    c2 = math.cos(q1 + q2)
    c3 = math.cos(q1 + q2 + q3)
    t3 = g * (masses[WRIST_TURNED_KG] * masses[WRIST_TURNED_CG_M] + payload_kg * masses[TIP_M]) * c3
    beyond_j3 = masses[WRIST_FIXED_KG] + masses[WRIST_TURNED_KG] + payload_kg
    t2 = g * (masses[LINK3_KG] * masses[LINK3_M] / 2 + beyond_j3 * masses[LINK3_M]) * c2 + t3
    beyond_j2 = masses[ELBOW_HW_KG] + masses[LINK3_KG] + beyond_j3
    t1 = g * (masses[LINK2_KG] * masses[LINK2_M] / 2 + beyond_j2 * masses[LINK2_M]) * c1 + t2
    return t1, t2, t3


def joints_tick(first: int, stop: int, now: float, fb_s: float, counts, currents_a, home, gravity_nm, duty_out,
                state, int_state, config, int_config, profile) -> int:
    """Run the tick of joints `first` .. `stop - 1`, inputs from MOTOR_FB (arrived at `fb_s`); return `stop`, or
    the index of the first joint whose tick the facade must run (nothing of it changed here)."""
    for k in range(first, stop):
        (pos_rad, vel_rad_s, offset_rad, count_s, last_duty, duty_requested, integ, duty_lo, duty_hi, pos_sp,
         vel_sp, target, profile_t0, settle_since, stall_since, trip_since, open_since, home_start) = state[k]
        (mode, err, homed, has_count, last_count, turns, missed, estimator_flags, segments, phase) = int_state[k]
        (est_dt, k_pos, k_vel, max_counts_per_tick, rad_per_count, dt, kp, kv, ki, aw, vcmd_max, relax,
         following_error, ff_vel, ff_acc, ff_torque, i_limit, i_limit_gain, current_stale_s, i_trip_a, i_trip_s,
         stall_duty, stall_vel, stall_time_s, open_duty, open_a, open_s, soft_min, soft_max, in_position,
         in_position_vel, settle_timeout_s, acc_limit, home_max_travel) = config[k]
        channel, stale_ticks, glitch_margin, has_gravity, moves_need_home = int_config[k]
        if segments == FACADE_PROFILE:
            return k                                         # a trajectory's curve: Axis.update samples it

        # ---- stage 0: encoder count -> estimator (SteadyStateEstimator.update)
        pos = pos_rad + vel_rad_s * est_dt                   # predict
        if fb_s != count_s:                                  # a new count arrived
            count = counts[channel]
            if has_count:
                delta = (count - last_count + 0x80000000) % 0x100000000 - 0x80000000   # across the 32-bit wrap
                limit = max_counts_per_tick * (missed + 1) + glitch_margin
                if not -limit <= delta <= limit:
                    return k                                 # ENCODER_GLITCH
                turns += delta
                measured = turns * rad_per_count + offset_rad
            else:                                            # the first count: where the estimate is
                has_count = 1
                turns = 0
                measured = offset_rad
            last_count = count
            missed = 0
            residual = measured - pos                        # correct
            pos += k_pos * residual
            vel_rad_s += k_vel * residual
            count_s = fb_s
        else:
            missed += 1
            if missed >= stale_ticks:
                return k                                     # ENCODER_STALE
        pos_rad = pos

        if mode == IDLE or mode == FAULT:                    # not driven: duty 0
            duty = 0.0
            u = duty_requested
        else:
            # ---- stage 1: setpoint and cascaded control
            if segments == 0:                                # holding where it is
                vel_sp = 0.0
                acc_sp = 0.0
            else:                                            # the profile at t (Profile.sample)
                motion = profile[k]
                t = now - profile_t0
                if t >= motion[DURATION_S]:
                    pos_sp = motion[END_POS_RAD]
                    vel_sp = motion[END_VEL_RAD_S]
                    acc_sp = 0.0
                else:
                    i = SEGMENTS + SEGMENT_COLUMNS * (segments - 1)
                    while i > SEGMENTS and motion[i] > t:
                        i -= SEGMENT_COLUMNS
                    since_start = t - motion[i]
                    if since_start < 0.0:
                        since_start = 0.0
                    seg_vel, seg_acc = motion[i + 2], motion[i + 3]
                    pos_sp = motion[i + 1] + since_start * (seg_vel + 0.5 * seg_acc * since_start)
                    vel_sp = seg_vel + seg_acc * since_start
                    acc_sp = seg_acc
                if mode == HOMING:                           # Homing.step: a phase's end, the switch, too far
                    if phase == HOME_BACKOFF:
                        if t >= motion[DURATION_S]:
                            return k                         # backed off: hold, homed
                    elif abs(pos - home_start) > home_max_travel:
                        return k                             # HOMING_FAILED
                    elif phase == HOME_START:
                        return k                             # the first tick: is it on the switch already?
                    elif phase == HOME_CLEAR:
                        if not home[channel]:
                            return k                         # off the switch: seek it
                    elif home[channel]:
                        return k                             # found the switch: the zero, then back off
                elif mode != HOLDING:                        # supervise the motion (Axis._supervise_motion)
                    if homed or not moves_need_home:         # the soft limits are on
                        if mode == JOGGING:                  # come to rest at the limit, one tick early
                            ahead = pos_sp + vel_sp * abs(vel_sp) / (2.0 * acc_limit) + vel_sp * dt
                            if (vel_sp > 0 and ahead >= soft_max) or (vel_sp < 0 and ahead <= soft_min):
                                return k
                        elif (pos > soft_max + in_position and vel_rad_s > 0) or (
                                pos < soft_min - in_position and vel_rad_s < 0):
                            return k
                    if mode == MOVING and t >= motion[DURATION_S]:      # the profile has ended: settling
                        if settle_since != settle_since:
                            settle_since = now
                        if (abs(target - pos) <= in_position and abs(vel_rad_s) <= in_position_vel) or (
                                now - settle_since >= settle_timeout_s):
                            return k                         # settled, or given up: the move's end
            pos_err = pos_sp - pos
            if pos_err > following_error or -pos_err > following_error:
                return k                                     # FOLLOWING_ERROR
            vel_cmd = vel_sp + kp * pos_err                  # position loop
            if vel_cmd > vcmd_max:
                vel_cmd = vcmd_max
            elif vel_cmd < -vcmd_max:
                vel_cmd = -vcmd_max
            vel_err = vel_cmd - vel_rad_s                    # velocity loop PI + feed-forward
            u = kv * vel_err + integ + ff_vel * vel_sp + ff_acc * acc_sp
            if has_gravity:
                u += ff_torque * gravity_nm[k]

            # ---- stage 2: current limit, saturation, anti-windup, debounced faults (Axis._limit)
            i_a = currents_a[channel]
            if now - fb_s > current_stale_s or i_a != i_a:
                return k                                     # CURRENT_STALE
            limited = 0
            over = i_a - i_limit
            if over > 0:                                     # above the limit: pull the upper bound down
                bound = last_duty if last_duty < duty_hi else duty_hi                  # min(hi, last)
                bound = bound - i_limit_gain * over
                duty_hi = bound if bound > -1.0 else -1.0                              # max(-1, .)
                limited = CURRENT_LIMITED
            elif duty_hi < 1.0:                              # below it: relax toward 1
                bound = duty_hi + relax
                duty_hi = bound if bound < 1.0 else 1.0                                # min(1, .)
            under = -i_limit - i_a
            if under > 0:                                    # below -limit: push the lower bound up
                bound = last_duty if last_duty > duty_lo else duty_lo                  # max(lo, last)
                bound = bound + i_limit_gain * under
                duty_lo = bound if bound < 1.0 else 1.0                                # min(1, .)
                limited = CURRENT_LIMITED
            elif duty_lo > -1.0:
                bound = duty_lo - relax
                duty_lo = bound if bound > -1.0 else -1.0                              # max(-1, .)
            err = (err & ~CURRENT_LIMITED) | limited
            # Debounced faults (Debounce.held): a `since` is the first tick of the condition's present run, NaN
            # while the condition is false; held for its time (> 0, so never on the first tick), the axis faults.
            over_current = abs(i_a) > i_trip_a
            trip_since = (trip_since if trip_since == trip_since else now) if over_current else NONE
            if now - trip_since >= i_trip_s:
                return k                                     # OVER_CURRENT
            duty = duty_hi if u > duty_hi else duty_lo if u < duty_lo else u
            open_circuit = (duty >= open_duty or duty <= -open_duty) and -open_a < i_a < open_a
            open_since = (open_since if open_since == open_since else now) if open_circuit else NONE
            if now - open_since >= open_s:
                return k                                     # OPEN_CIRCUIT
            if mode == HOLDING and -in_position <= pos_err <= in_position:
                integ += dt * ((duty - u) * aw)              # held in position: static friction holds it
            else:
                integ += dt * (ki * vel_err + (duty - u) * aw)   # back-calculation anti-windup
            # stall: asking for more than it gets (saturated or current-limited) or for high duty, yet not moving
            stalled = (duty != u or u >= stall_duty or u <= -stall_duty) and -stall_vel < vel_rad_s < stall_vel
            stall_since = (stall_since if stall_since == stall_since else now) if stalled else NONE
            if now - stall_since >= stall_time_s:
                return k                                     # STALL

        state[k][:] = (pos_rad, vel_rad_s, offset_rad, count_s, duty, u, integ, duty_lo, duty_hi, pos_sp, vel_sp,
                       target, profile_t0, settle_since, stall_since, trip_since, open_since, home_start)
        int_state[k][:] = (mode, err, homed, has_count, last_count, turns, missed, 0, segments, phase)
        duty_out[channel] = duty
    return stop


def arm_joints_tick(stop: int, now: float, fb_s: float, g: float, payload_kg: float, masses, counts, currents_a,
                    home, gravity_nm, duty_out, state, int_state, config, int_config, profile) -> int:
    """The arm's joints' tick from the first: J1..J3's gravity torques into `gravity_nm` (rows 0..2; `g` 0, none)
    from where the joints are before any of them ticks, then `joints_tick` of joints 0 .. `stop - 1`; returns what
    that returns. The torques stay for the joints a later call, or `Axis.update`, ticks."""
    if g:
        torques = holding_torques_nm(state[0][POS_RAD], state[1][POS_RAD], state[2][POS_RAD], g, payload_kg, masses)
    else:
        torques = (0.0, 0.0, 0.0)          # gravity set to 0 (orbit): no feed-forward
    for k in range(GRAVITY_ROWS):
        gravity_nm[k] = torques[k]
    return joints_tick(0, stop, now, fb_s, counts, currents_a, home, gravity_nm, duty_out, state, int_state, config,
                       int_config, profile)
