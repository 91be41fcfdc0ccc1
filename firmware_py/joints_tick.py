"""A joint's tick, the one implementation: one function over flat per-joint rows of numbers.

`joints_tick` runs, for joints `first` .. `stop - 1` in that order, each joint's whole tick: the
estimator, the setpoint, the supervision of a motion (soft limits, the end of a move, homing's
phases), the cascaded control, the current limit, the saturation, the anti-windup and the
debounced fault checks. It reads and writes nothing but numbers in sequences indexed by joint
(lists, or numpy arrays of the same shape, for numba: firmware_py/joints_compiled.py): no
objects, enums or callables, the constants precomputed by the facade (firmware_py/joint_bank.py,
`BankedAxis`), flags and modes as ints.

Where a tick needs what only the facade has (a Python object: a motion profile to make, an
outcome or a fault to report, a trajectory's curve to sample), the function writes the joint's
state as far as the tick has got, names the event in the joint's EVENT column and returns the
joint's index. The facade acts (`BankedAxis.act`): a fault ends the tick there (duty 0); the
other events leave the setpoint to follow in the TICK_* columns and the point to go on from in
ENTRY, and `joints_tick` is called again from that joint. So the arithmetic of a tick exists
here only, and a joint's tick, the facade's part included, happens exactly where it would in a
loop over the joints: what one joint's tick does to the others (a fault's safe state) happens
before the next joint ticks. The events:

  EV_FAULT    a fault raised in the tick (the AxisError bits in RAISED): the encoder's (no new
              count for `stale_ticks` ticks, a count jump no motion could make), the following
              error, a stale or NaN current, or an over-current, open-circuit or stall condition
              held long enough;
  EV_SETPOINT a trajectory's curve (firmware_py/hermite.py; its row holds no segments,
              PROFILE_SEGMENTS is FACADE_PROFILE): the facade samples it, the tick goes on from
              SUPERVISE;
  EV_MOTION   the supervision's decision (MOTION: a soft limit's stop, a move's end, a homing
              phase's end, homing failed), the setpoint sampled in TICK_*: the facade acts (a stop
              profile, the hold, the next homing phase) and the tick goes on from CONTROL with the
              setpoint it gives, or ends (homing failed).

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
"none". Per-channel inputs (`counts`, `currents_a`, `home`) and the output `duty_out` are indexed
by the joint's HAL channel (`int_config` CHANNEL); `gravity_nm` by joint. The counts arrived at
`count_s` (NaN: none arrived), the currents at `current_s` (NaN: none: stale).
"""
from __future__ import annotations

import math

from protocol.states import AxisMode

# state: floats that change every tick; TICK_*: the setpoint a handed-back tick goes on with
(POS_RAD, VEL_RAD_S, OFFSET_RAD, COUNT_S, DUTY, DUTY_REQUESTED, INTEG, DUTY_LO, DUTY_HI, POS_SP_RAD, VEL_SP_RAD_S,
 TARGET_RAD, PROFILE_T0_S, SETTLE_SINCE_S, STALL_SINCE_S, TRIP_SINCE_S, OPEN_SINCE_S, HOME_START_RAD,
 TICK_POS_SP, TICK_VEL_SP, TICK_ACC_SP) = range(21)
STATE_COLUMNS = 21
# int_state: mode, bits and counters; ENTRY, EVENT, RAISED, MOTION: a handed-back tick's
(MODE, ERR, HOMED, HAS_COUNT, LAST_COUNT, TURNS_COUNTS, MISSED_TICKS, ESTIMATOR_FLAGS, PROFILE_SEGMENTS,
 HOMING_PHASE, ENTRY, EVENT, RAISED, MOTION) = range(14)
INT_STATE_COLUMNS = 14
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
FACADE_PROFILE = -1       # PROFILE_SEGMENTS of a profile this function does not evaluate: the facade samples it
PROFILE_COLUMNS = SEGMENTS + SEGMENT_COLUMNS * MAX_SEGMENTS

# ENTRY: where a joint's tick starts: at its beginning, at the supervision with the setpoint in TICK_* (a
# trajectory's), at the control with the setpoint in TICK_* (after the facade's act on a motion event)
START, SUPERVISE, CONTROL = range(3)
# EVENT: why the tick was handed over (module docstring)
EV_NONE, EV_FAULT, EV_SETPOINT, EV_MOTION = range(4)
# MOTION: the supervision's decision
SOFT_LIMIT_STOP, MOVE_SETTLED, MOVE_GAVE_UP = range(1, 4)
HOMING_FAILED, HOMING_ON_SWITCH, HOMING_OFF_SWITCH, HOMING_FOUND, HOMING_BACKED_OFF = range(4, 9)   # homing's
# AxisError's bits (firmware_py/axis.py holds the enum and checks it against these)
(ENCODER_STALE, ENCODER_GLITCH, CURRENT_STALE, STALL, FOLLOWING_ERROR, OVER_CURRENT, CURRENT_LIMITED,
 OPEN_CIRCUIT) = (1 << 0, 1 << 1, 1 << 2, 1 << 3, 1 << 4, 1 << 6, 1 << 8, 1 << 9)

IDLE, MOVING, JOGGING, HOMING, HOLDING, FAULT = (int(AxisMode.IDLE), int(AxisMode.MOVING), int(AxisMode.JOGGING),
                                                 int(AxisMode.HOMING), int(AxisMode.HOLDING), int(AxisMode.FAULT))
# homing's phases (firmware_py/homing.py): first tick (is the switch already closed?), leave the switch, seek it,
# back off
HOME_START, HOME_CLEAR, HOME_SEEK, HOME_BACKOFF = range(4)
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


def stopping_distance(vel_rad_s: float, acc_max_rad_s2: float) -> float:
    """Signed distance to rest when decelerating at the limit (`profiles.stopping_distance`)."""
    return vel_rad_s * abs(vel_rad_s) / (2.0 * acc_max_rad_s2)


def sample_profile(motion, segments: int, t: float) -> tuple:
    """A motion profile's (pos_rad, vel_rad_s, acc_rad_s2) at `t` seconds after its start (`profiles.Profile.sample`):
    `motion` its row (DURATION_S, END_POS_RAD, END_VEL_RAD_S, then `segments` segments), constant acceleration in
    each segment, the end's position and speed from its duration on."""
    if t >= motion[DURATION_S]:
        return motion[END_POS_RAD], motion[END_VEL_RAD_S], 0.0
    i = SEGMENTS + SEGMENT_COLUMNS * (segments - 1)
    while i > SEGMENTS and motion[i] > t:
        i -= SEGMENT_COLUMNS
    since_start = t - motion[i]
    if since_start < 0.0:
        since_start = 0.0
    vel, acc = motion[i + 2], motion[i + 3]
    return motion[i + 1] + since_start * (vel + 0.5 * acc * since_start), vel + acc * since_start, acc


def count_step(new_count: bool, count: int, has_count: int, last_count: int, turns: int, missed: int,
               offset_rad: float, rad_per_count: float, max_counts_per_tick: float, stale_ticks: int,
               glitch_margin: int) -> tuple:
    """A tick's raw count through the estimator's checks (`_CountTracker`, firmware_py/estimator.py): the 32-bit
    wrap, staleness (no new count for `stale_ticks` ticks) and glitches (a jump no motion could make in the ticks
    since the last accepted count: the sample dropped). Returns (z, has_count, last_count, turns, missed, flags):
    z the measured position (NaN: none this tick), flags ENCODER_STALE | ENCODER_GLITCH."""
    if not new_count:
        missed += 1
        return NONE, has_count, last_count, turns, missed, ENCODER_STALE if missed >= stale_ticks else 0
    if not has_count:                                        # the first count: where the estimate is
        return offset_rad, 1, count, 0, 0, 0
    delta = (count - last_count + 0x80000000) % 0x100000000 - 0x80000000     # across the 32-bit wrap
    limit = max_counts_per_tick * (missed + 1) + glitch_margin
    if -limit <= delta <= limit:
        turns += delta
        return turns * rad_per_count + offset_rad, 1, count, turns, 0, 0
    missed += 1
    return NONE, has_count, last_count, turns, missed, ENCODER_GLITCH | (ENCODER_STALE if missed >= stale_ticks
                                                                          else 0)


def filter_step(pos_rad: float, vel_rad_s: float, z: float, dt_s: float, k_pos: float, k_vel: float) -> tuple:
    """The constant-velocity filter with steady-state gains (`SteadyStateEstimator`): predict, and correct with the
    measured position `z` (NaN: none). Returns (pos_rad, vel_rad_s)."""
    pos_rad = pos_rad + vel_rad_s * dt_s                     # predict
    if z == z:
        residual = z - pos_rad                               # correct
        pos_rad += k_pos * residual
        vel_rad_s += k_vel * residual
    return pos_rad, vel_rad_s


def joints_tick(first: int, stop: int, now: float, count_s: float, current_s: float, counts, currents_a, home,
                gravity_nm, duty_out, state, int_state, config, int_config, profile) -> int:
    """Run the tick of joints `first` .. `stop - 1` (each from its ENTRY); return `stop`, or the index of the first
    joint whose tick needs the facade (its EVENT set, its state written as far as the tick got)."""
    for k in range(first, stop):
        (pos_rad, vel_rad_s, offset_rad, last_count_s, last_duty, duty_requested, integ, duty_lo, duty_hi, pos_sp,
         vel_sp, target, profile_t0, settle_since, stall_since, trip_since, open_since, home_start, tick_pos_sp,
         tick_vel_sp, tick_acc_sp) = state[k]
        (mode, err, homed, has_count, last_count, turns, missed, estimator_flags, segments, phase, entry, _, _,
         _) = int_state[k]
        (est_dt, k_pos, k_vel, max_counts_per_tick, rad_per_count, dt, kp, kv, ki, aw, vcmd_max, relax,
         following_error, ff_vel, ff_acc, ff_torque, i_limit, i_limit_gain, current_stale_s, i_trip_a, i_trip_s,
         stall_duty, stall_vel, stall_time_s, open_duty, open_a, open_s, soft_min, soft_max, in_position,
         in_position_vel, settle_timeout_s, acc_limit, home_max_travel) = config[k]
        channel, stale_ticks, glitch_margin, has_gravity, moves_need_home = int_config[k]
        event = EV_NONE
        raised = 0
        motion = 0
        duty = last_duty
        u = duty_requested
        acc_sp = 0.0
        holding = False                                      # HOLDING at the tick's start (the integrator's rule)
        driven = True
        if entry == START:
            # ---- stage 0: encoder count -> estimator (firmware_py/estimator.py uses the same two functions)
            new_count = count_s == count_s and count_s != last_count_s      # a new count arrived
            if new_count:
                last_count_s = count_s
            z, has_count, last_count, turns, missed, estimator_flags = count_step(
                new_count, counts[channel], has_count, last_count, turns, missed, offset_rad, rad_per_count,
                max_counts_per_tick, stale_ticks, glitch_margin)
            pos_rad, vel_rad_s = filter_step(pos_rad, vel_rad_s, z, est_dt, k_pos, k_vel)
            if estimator_flags:
                event = EV_FAULT
                raised = estimator_flags
            elif mode == IDLE or mode == FAULT:              # not driven: duty 0
                driven = False
                duty = 0.0
            elif segments == FACADE_PROFILE:
                event = EV_SETPOINT                          # a trajectory's curve: the facade samples it
            else:
                # ---- stage 1: the setpoint
                holding = mode == HOLDING
                if segments == 0:                            # holding where it is
                    tick_pos_sp = pos_sp
                    tick_vel_sp = 0.0
                    tick_acc_sp = 0.0
                else:                                        # the profile at t
                    tick_pos_sp, tick_vel_sp, tick_acc_sp = sample_profile(profile[k], segments, now - profile_t0)
                    entry = SUPERVISE if mode != HOLDING else CONTROL
                if entry == START:
                    entry = CONTROL
        if event == EV_NONE and driven and entry == SUPERVISE:
            # ---- stage 1b: supervise the motion (Axis._act_on acts on the decision)
            t = now - profile_t0
            duration = profile[k][DURATION_S]
            if mode == HOMING:                               # homing's phases (firmware_py/homing.py)
                if phase == HOME_BACKOFF:
                    if t >= duration:
                        motion = HOMING_BACKED_OFF           # backed off: hold, homed
                elif abs(pos_rad - home_start) > home_max_travel:
                    motion = HOMING_FAILED
                elif phase == HOME_START:                    # the first tick: is it on the switch already?
                    if home[channel]:
                        motion = HOMING_ON_SWITCH            # move off it first
                    else:
                        phase = HOME_SEEK
                elif phase == HOME_CLEAR:
                    if not home[channel]:
                        motion = HOMING_OFF_SWITCH           # off the switch: seek it
                elif home[channel]:
                    motion = HOMING_FOUND                    # found the switch: the zero, then back off
            elif mode != HOLDING:
                if homed or not moves_need_home:             # the soft limits are on
                    if mode == JOGGING:                      # come to rest at the limit, one tick early
                        ahead = tick_pos_sp + stopping_distance(tick_vel_sp, acc_limit) + tick_vel_sp * dt
                        if (tick_vel_sp > 0 and ahead >= soft_max) or (tick_vel_sp < 0 and ahead <= soft_min):
                            motion = SOFT_LIMIT_STOP
                    elif (pos_rad > soft_max + in_position and vel_rad_s > 0) or (
                            pos_rad < soft_min - in_position and vel_rad_s < 0):
                        motion = SOFT_LIMIT_STOP
                if motion == 0 and mode == MOVING and t >= duration:   # the profile has ended: settling
                    if settle_since != settle_since:
                        settle_since = now
                    if abs(target - pos_rad) <= in_position and abs(vel_rad_s) <= in_position_vel:
                        motion = MOVE_SETTLED
                    elif now - settle_since >= settle_timeout_s:
                        motion = MOVE_GAVE_UP
            if motion:
                event = EV_MOTION
            else:
                entry = CONTROL
        if event == EV_NONE and driven:
            # ---- stage 2: cascaded control, current limit, saturation, anti-windup, debounced faults
            pos_sp = tick_pos_sp
            vel_sp = tick_vel_sp
            acc_sp = tick_acc_sp
            pos_err = pos_sp - pos_rad
            i_a = currents_a[channel]
            if pos_err > following_error or -pos_err > following_error:
                raised = FOLLOWING_ERROR
            elif not now - current_s <= current_stale_s or i_a != i_a:
                raised = CURRENT_STALE
            else:
                vel_cmd = vel_sp + kp * pos_err              # position loop
                if vel_cmd > vcmd_max:
                    vel_cmd = vcmd_max
                elif vel_cmd < -vcmd_max:
                    vel_cmd = -vcmd_max
                vel_err = vel_cmd - vel_rad_s                # velocity loop PI + feed-forward
                new_u = kv * vel_err + integ + ff_vel * vel_sp + ff_acc * acc_sp
                if has_gravity:
                    new_u += ff_torque * gravity_nm[k]
                limited = 0
                over = i_a - i_limit
                if over > 0:                                 # above the limit: pull the upper bound down
                    bound = last_duty if last_duty < duty_hi else duty_hi              # min(hi, last)
                    bound = bound - i_limit_gain * over
                    duty_hi = bound if bound > -1.0 else -1.0                          # max(-1, .)
                    limited = CURRENT_LIMITED
                elif duty_hi < 1.0:                          # below it: relax toward 1
                    bound = duty_hi + relax
                    duty_hi = bound if bound < 1.0 else 1.0                            # min(1, .)
                under = -i_limit - i_a
                if under > 0:                                # below -limit: push the lower bound up
                    bound = last_duty if last_duty > duty_lo else duty_lo              # max(lo, last)
                    bound = bound + i_limit_gain * under
                    duty_lo = bound if bound < 1.0 else 1.0                            # min(1, .)
                    limited = CURRENT_LIMITED
                elif duty_lo > -1.0:
                    bound = duty_lo - relax
                    duty_lo = bound if bound > -1.0 else -1.0                          # max(-1, .)
                err = (err & ~CURRENT_LIMITED) | limited
                # Debounced faults (Debounce.held): a `since` is the first tick of the condition's present run, NaN
                # while the condition is false; held for its time (> 0, so never on the first tick), the axis faults.
                over_current = abs(i_a) > i_trip_a
                trip_since = (trip_since if trip_since == trip_since else now) if over_current else NONE
                if now - trip_since >= i_trip_s:
                    raised = OVER_CURRENT
                else:
                    new_duty = duty_hi if new_u > duty_hi else duty_lo if new_u < duty_lo else new_u
                    open_circuit = (new_duty >= open_duty or new_duty <= -open_duty) and -open_a < i_a < open_a
                    open_since = (open_since if open_since == open_since else now) if open_circuit else NONE
                    if now - open_since >= open_s:
                        raised = OPEN_CIRCUIT
                    else:
                        if holding and -in_position <= pos_err <= in_position:
                            integ += dt * ((new_duty - new_u) * aw)    # held in position: static friction holds it
                        else:
                            integ += dt * (ki * vel_err + (new_duty - new_u) * aw)   # back-calculation anti-windup
                        # stall: asking for more than it gets (saturated or current-limited) or for high duty, yet not
                        # moving
                        stalled = ((new_duty != new_u or new_u >= stall_duty or new_u <= -stall_duty)
                                   and -stall_vel < vel_rad_s < stall_vel)
                        stall_since = (stall_since if stall_since == stall_since else now) if stalled else NONE
                        if now - stall_since >= stall_time_s:
                            raised = STALL
                        else:
                            duty = new_duty
                            u = new_u
            if raised:
                event = EV_FAULT
        state[k][:] = (pos_rad, vel_rad_s, offset_rad, last_count_s, duty, u, integ, duty_lo, duty_hi, pos_sp, vel_sp,
                       target, profile_t0, settle_since, stall_since, trip_since, open_since, home_start, tick_pos_sp,
                       tick_vel_sp, tick_acc_sp)
        int_state[k][:] = (mode, err, homed, has_count, last_count, turns, missed, estimator_flags, segments, phase,
                           START, event, raised, motion)
        if event != EV_NONE:
            return k
        duty_out[channel] = duty
    return stop


def arm_joints_tick(stop: int, now: float, count_s: float, current_s: float, g: float, payload_kg: float, masses,
                    counts, currents_a, home, gravity_nm, duty_out, state, int_state, config, int_config,
                    profile) -> int:
    """The arm's joints' tick from the first: J1..J3's gravity torques into `gravity_nm` (rows 0..2; `g` 0, none)
    from where the joints are before any of them ticks, then `joints_tick` of joints 0 .. `stop - 1`; returns what
    that returns. The torques stay for the joints a later call ticks."""
    if g:
        torques = holding_torques_nm(state[0][POS_RAD], state[1][POS_RAD], state[2][POS_RAD], g, payload_kg, masses)
    else:
        torques = (0.0, 0.0, 0.0)          # gravity set to 0 (orbit): no feed-forward
    for k in range(GRAVITY_ROWS):
        gravity_nm[k] = torques[k]
    return joints_tick(0, stop, now, count_s, current_s, counts, currents_a, home, gravity_nm, duty_out, state,
                       int_state, config, int_config, profile)
