"""The one-process world's fast loop: its three 1 kHz tasks run many ticks per call, between events.

In the lock-step world (`World` on a simulated clock without a stopwatch) the controller's `arm` and
`hal` tasks and the plant's `plant` task run back to back at every tick, in that order, and nothing
else runs between them for up to ten ticks. `FastLoop` is `Scheduler.run_ahead`'s runner for the
three: one call of `fast_ticks`, compiled by numba with the kernels (`ASPOD_COMPILED=1`), runs as
many of those ticks as it can, each as the three tasks would run it:

  arm    the joints' tick (`arm_joints_tick`, firmware_py/joints_tick.py) on the feedback of the tick
         before, the gripper's tracking (`track`, firmware_py/gripper.py), MOTOR_CMD's duties
         (`quantized_duty`, firmware_py/hal.py), its enables and brakes and `alive`;
  plant  MOTOR_CMD taken, the arm plant's tick (`arm_plant_tick`, hil_sim/arm_tick.py), the box's
         electronics (`electronics_step`, hil_sim/plant.py), MOTOR_FB's counts and currents as the
         bus carries them, PLANT_SYNC;
  hal    the feedback and the tick read (the controller's HAL inputs).

Each of those functions is the one the tasks call: nothing of a tick is written twice. What the
frames would carry is handed over as numbers; the endpoints' counters, the command holders, the
HAL inputs and the scheduler's statistics end as the tasks would leave them.

A tick that needs Python is left to the tasks. Known before the call, it bounds the ticks offered
(`FastLoop.run`): a slow task's time (the scheduler offers only the ticks before the next other
task), the plant's periodic frames (ANALOG_IN, DIGITAL_IN, the tracker's step), CTRL_OUTPUTS due,
a command holder expiring, the noise batch used up. Met inside a tick, the kernel puts back
everything the tick changed and stops before it: a joint's event (a fault, a motion's course change:
the facade's; a trajectory's curve is sampled here, `hermite_sample`, as the facade samples it), the
end or time-out of a gripper's move, a duty or a current that is not a number. A switch edge ends
the ticks with its own (DIGITAL_IN goes out at once: `FastLoop._finish`). And the fast loop stands
aside while anything else looks at the bus (a HAL log, a third node, a wrapped endpoint, frames
packed to bytes; frames waiting are read first, as both nodes' first polls would), and in the plain
(not compiled) world, whose tasks run as they always have.
"""
from __future__ import annotations

import struct
from typing import Optional

import numpy as np

from firmware_py.arm import GRIPPER_INDEX
from firmware_py.gripper_tick import GOES_ON, moving_tick, track
from firmware_py.hal import quantized_duty
from firmware_py import joints_tick as jt
from firmware_py.hermite import HermiteProfile, hermite_sample
from firmware_py.joints_tick import arm_joints_tick, joints_tick
from hil_sim import arm_tick as at
from hil_sim.plant import electronics_step
from protocol.states import ARM_CHANNELS, AxisMode

# `fast_ticks`'s scalars: the float ones (`f`) ...
(F_ORIGIN, F_PERIOD, F_FB_S, F_G, F_PAYLOAD, F_STEP, F_HOLD_DUTY, F_REF_M, F_M_PER_COUNT, F_VEL_M_S, F_VEL_S,
 F_OPENING_M, F_GRIP_DUTY, F_H_S, F_SUPPLY_TRUE_V, F_TEMP_TRUE_C, F_CURRENT_A, F_SUPPLY_V, F_TEMP_C, F_BRIDGES_A,
 F_DECAY, F_EMF_V, F_AMBIENT_C, F_IDLE_A, F_ENABLED_A, F_SOURCE_OHM, F_ON_OHM, F_RTH, F_SUPPLY_NOISE_V,
 F_TEMP_NOISE_C, F_CURRENT_LO, F_CURRENT_HI, F_CURRENT_SCALE, F_DT, F_TRACKER_DT, F_STARTED_S, F_STILL_SINCE,
 F_GRIP_CURRENT_A, F_GRIP_MOVE_DUTY, F_GRIP_TIMEOUT_S) = range(40)
FLOATS = 40
# ... and the integer ones (`i`)
(I_N0, I_ALIVE, I_NODE_TICK, I_NOISE_AT, I_REF_COUNT, I_VEL_COUNT, I_GRIPPED, I_HOLDING, I_ALLOWED,
 I_OUTPUTS_ENABLED, I_BRAKE_ALL, I_SUBSTEPS, I_SIZE, I_TRACKER, I_MOVING, I_DIRECTION, I_LAST_COUNT,
 I_CLOSED_SWITCH, I_OPEN_SWITCH, I_EDGE, I_GRIPPER, I_HANDED) = range(22)
INTS = 22
_ROUND = 6755399441055744.0       # 1.5 * 2**52: x + _ROUND - _ROUND rounds x half to even (|x| < 2**51)


def copy_groups(state, int_state, gravity_nm, duties, command, arm_state, flags, arm_counts, to_state, to_int_state,
                to_gravity_nm, to_duties, to_command, to_arm_state, to_flags, to_arm_counts) -> None:
    """The groups a tick changes, copied into the `to_` ones (`fast_ticks` keeps each tick's start to put it back)."""
    to_state[:, :] = state
    to_int_state[:, :] = int_state
    to_gravity_nm[:] = gravity_nm
    to_duties[:] = duties
    to_command[:, :] = command
    to_arm_state[:, :] = arm_state
    to_flags[:, :] = flags
    to_arm_counts[:, :] = arm_counts


def fast_ticks(ticks, f, i, masses, counts_in, currents_in, home, switches_sent, brakes, noise, values,
               curve_times, curve_coefficients, curve_knots, curve_ends, state, int_state, config, int_config, profile,
               gravity_nm, duties, command, arm_state, table, flags, arm_counts, constants,
               saved_state, saved_int_state, saved_gravity, saved_duties, saved_command, saved_arm_state, saved_flags,
               saved_arm_counts):
    """Up to `ticks` ticks of the world's arm, plant and hal tasks (the module docstring); returns the ticks run.

    The groups are the joints' (`state` .. `duties`: a `JointBank`'s) and the arm plant's (`command` ..
    `constants`: an `ArmTick`'s), changed in place; `f` and `i` the other numbers (the F_ and I_ columns), their
    changing ones written back as of the last tick run; `counts_in`, `currents_in` the controller's HAL inputs,
    `values` MOTOR_CMD's last values (duties, enables, brakes); the `curve_` rows each joint's trajectory curve
    (`FastLoop._load_curves`). A tick that meets an event is put back as it was (the `saved_` arrays) and not
    counted."""
    size = i[I_SIZE]
    gr = i[I_GRIPPER]
    n = duties.shape[0]
    origin, period, n0 = f[F_ORIGIN], f[F_PERIOD], i[I_N0]
    g, payload, step = f[F_G], f[F_PAYLOAD], f[F_STEP]
    hold = -f[F_HOLD_DUTY] if i[I_HOLDING] != 0 and i[I_GRIPPED] != 0 else 0.0
    allowed = i[I_ALLOWED] != 0
    outputs_enabled = i[I_OUTPUTS_ENABLED] != 0
    brake_all = i[I_BRAKE_ALL] != 0
    tracker = i[I_TRACKER] != 0
    lo, hi, scale = f[F_CURRENT_LO], f[F_CURRENT_HI], f[F_CURRENT_SCALE]
    fb_s = f[F_FB_S]
    opening_m, vel_m_s, vel_count, vel_s = f[F_OPENING_M], f[F_VEL_M_S], i[I_VEL_COUNT], f[F_VEL_S]
    alive, node_tick, noise_at = i[I_ALIVE], i[I_NODE_TICK], i[I_NOISE_AT]
    supply_true_v, temp_true_c, current_a = f[F_SUPPLY_TRUE_V], f[F_TEMP_TRUE_C], f[F_CURRENT_A]
    supply_v, temp_c, bridges_a, tracker_dt = f[F_SUPPLY_V], f[F_TEMP_C], f[F_BRIDGES_A], f[F_TRACKER_DT]
    grip_duty = f[F_GRIP_DUTY]
    moving = i[I_MOVING] != 0
    still_since, last_count = f[F_STILL_SINCE], i[I_LAST_COUNT]
    done = 0
    edge = False
    handed = committed_handed = 0
    while done < ticks:
        now = origin + (n0 + done) * period
        copy_groups(state, int_state, gravity_nm, duties, command, arm_state, flags, arm_counts, saved_state,
                    saved_int_state, saved_gravity, saved_duties, saved_command, saved_arm_state, saved_flags,
                    saved_arm_counts)
        # ---- arm: the joints on the feedback of the tick before, the gripper, MOTOR_CMD
        k = arm_joints_tick(size, now, fb_s, fb_s, g, payload, masses, counts_in, currents_in, home, gravity_nm, duties,
                            state, int_state, config, int_config, profile)
        while k < size and int_state[k, jt.EVENT] == jt.EV_SETPOINT and curve_knots[k] >= 2:
            # a trajectory's curve, as the facade samples it (`BankedAxis.act`), and the joint's tick goes on
            int_state[k, jt.EVENT] = jt.EV_NONE
            ends = curve_ends[k]
            state[k, jt.TICK_POS_SP], state[k, jt.TICK_VEL_SP], state[k, jt.TICK_ACC_SP] = hermite_sample(
                curve_times[k], curve_coefficients[k], curve_knots[k], now - state[k, jt.PROFILE_T0_S], ends[0],
                ends[1], ends[2], ends[3], ends[4])
            int_state[k, jt.ENTRY] = jt.SUPERVISE
            handed += 1
            k = joints_tick(k, size, now, fb_s, fb_s, counts_in, currents_in, home, gravity_nm, duties, state,
                            int_state, config, int_config, profile)
        event = k < size
        edge = False
        t_opening, t_vel, t_vel_count, t_vel_s = track(now, counts_in[gr], i[I_REF_COUNT], f[F_REF_M],
                                                       f[F_M_PER_COUNT], vel_m_s, vel_count, vel_s)
        t_still, t_last_count, t_grip = still_since, last_count, hold
        if moving:
            ended, t_still, t_last_count, t_grip = moving_tick(
                now, counts_in[gr], currents_in[gr], i[I_CLOSED_SWITCH] != 0, i[I_OPEN_SWITCH] != 0, i[I_DIRECTION],
                f[F_STARTED_S], still_since, last_count, f[F_GRIP_CURRENT_A], f[F_GRIP_MOVE_DUTY], f[F_GRIP_TIMEOUT_S])
            if ended != GOES_ON:
                event = True                         # the move ends (or times out): the facade's
        for c in range(n):
            d = (t_grip if c == gr else duties[c]) if allowed else 0.0
            if not d == d:
                event = True                         # NaN: MOTOR_CMD's checked path refuses it (the tasks')
            command[at.DUTY, c] = quantized_duty(d, step)
            off = brakes[c] or not allowed
            command[at.ENABLE, c] = 0.0 if off else 1.0
            command[at.BRAKE, c] = 1.0 if off else 0.0
        # ---- plant: the arm's tick, the electronics, the readouts as MOTOR_FB carries them
        if not event:
            drawn, squares = at.arm_plant_tick(f[F_H_S], i[I_SUBSTEPS], supply_true_v, outputs_enabled, brake_all,
                                               command, arm_state, table, flags, arm_counts, constants)
            t_current, t_supply_true, t_temp_true, t_supply_v, t_temp_c = electronics_step(
                drawn, squares, outputs_enabled, temp_true_c, f[F_DECAY], noise[noise_at], noise[noise_at + 1],
                f[F_EMF_V], f[F_AMBIENT_C], f[F_IDLE_A], f[F_ENABLED_A], f[F_SOURCE_OHM], f[F_ON_OHM], f[F_RTH],
                f[F_SUPPLY_NOISE_V], f[F_TEMP_NOISE_C])
            for c in range(n):
                if (flags[at.HOME, c] != switches_sent[0, c] or flags[at.LIMIT_LO, c] != switches_sent[1, c]
                        or flags[at.LIMIT_HI, c] != switches_sent[2, c]):
                    edge = True                      # a switch edge: DIGITAL_IN goes out at once (the last tick)
                v = arm_state[at.CURRENT_A, c]
                if not v == v:
                    event = True                     # NaN: not what MOTOR_FB carries
        if event:
            copy_groups(saved_state, saved_int_state, saved_gravity, saved_duties, saved_command, saved_arm_state,
                        saved_flags, saved_arm_counts, state, int_state, gravity_nm, duties, command, arm_state, flags,
                        arm_counts)          # the tick put back as it was
            break
        # ---- hal: the feedback and the tick, as the bus carries them
        for c in range(n):
            values[c], values[n + c] = command[at.DUTY, c], command[at.ENABLE, c]
            values[2 * n + c] = command[at.BRAKE, c]
            counts_in[c] = arm_counts[at.COUNTS, c] & 0xFFFFFFFF
            v = arm_state[at.CURRENT_A, c]
            v = lo if v < lo else hi if v > hi else v
            currents_in[c] = (v / scale + _ROUND - _ROUND) * scale
        fb_s = now
        grip_duty, still_since, last_count = t_grip, t_still, t_last_count
        opening_m, vel_m_s, vel_count, vel_s = t_opening, t_vel, t_vel_count, t_vel_s
        alive = (alive + 1) & 0xFF
        supply_true_v, temp_true_c, current_a, supply_v, temp_c = (t_supply_true, t_temp_true, t_current, t_supply_v,
                                                                   t_temp_c)
        bridges_a = drawn
        noise_at += 2
        if tracker:
            tracker_dt += f[F_DT]
        node_tick += 1
        done += 1
        committed_handed = handed
        if edge:
            break
    f[F_FB_S], f[F_OPENING_M], f[F_VEL_M_S], f[F_VEL_S] = fb_s, opening_m, vel_m_s, vel_s
    f[F_SUPPLY_TRUE_V], f[F_TEMP_TRUE_C], f[F_CURRENT_A], f[F_SUPPLY_V], f[F_TEMP_C] = (supply_true_v, temp_true_c,
                                                                                        current_a, supply_v, temp_c)
    f[F_BRIDGES_A], f[F_TRACKER_DT], f[F_GRIP_DUTY] = bridges_a, tracker_dt, grip_duty
    i[I_ALIVE], i[I_NODE_TICK], i[I_NOISE_AT], i[I_VEL_COUNT] = alive, node_tick, noise_at, vel_count
    f[F_STILL_SINCE], i[I_LAST_COUNT], i[I_EDGE], i[I_HANDED] = still_since, last_count, edge, committed_handed
    return done


class FastLoop:
    """`Scheduler.run_ahead`'s runner for a `World`'s `arm`, `plant` and `hal` tasks (the module docstring).

    `run(origin_s, period_s, n, ticks)` offers the ticks at `origin_s + k * period_s` for k from n; it runs what
    `fast_ticks` can of them and returns how many (0: the tasks run the first themselves). `ticks_run` and
    `calls` count them."""

    def __init__(self, world) -> None:
        self.world = world
        controller = world.controller
        self.controller = controller
        self.arm = controller.arm
        self.hal = controller.hal
        self.node = world.plant_node
        self.plant = self.node.plant
        self.arm_tick = self.plant._arm_tick
        bank = self.arm.bank
        self.bank = bank
        n = len(self.arm.channels)
        self.f = np.zeros(FLOATS)
        self.i = np.zeros(INTS, np.int64)
        self.counts_in = np.zeros(n, np.int64)
        self.currents_in = np.zeros(n)
        self.home = np.zeros(n, np.bool_)
        self.switches_sent = np.zeros((3, n), np.bool_)
        self.brakes = np.zeros(n, np.bool_)
        self.values = np.zeros(3 * n)
        # the scalars go in as one pack each (numpy takes a tenth of a microsecond an item set)
        self._pack_floats = struct.Struct(f"{FLOATS}d").pack_into
        self._pack_ints = struct.Struct(f"{INTS}q").pack_into
        self._unpack_floats = struct.Struct(f"{FLOATS}d").unpack_from
        self._unpack_ints = struct.Struct(f"{INTS}q").unpack_from
        fb = self.node.codec.database.get_message_by_name("MOTOR_FB")
        self.current_scale = float(fb.get_signal_by_name(f"current_{ARM_CHANNELS[0]}").scale)
        self._saved = (np.empty_like(bank.state), np.empty_like(bank.int_state), np.empty_like(bank.gravity_nm),
                       np.empty_like(bank.duties), np.empty_like(self.arm_tick.command),
                       np.empty_like(self.arm_tick.state), np.empty_like(self.arm_tick.flags),
                       np.empty_like(self.arm_tick.counts))
        # each joint's trajectory curve (a `HermiteProfile`), as rows: knot times, segments' coefficients, knots
        # (0: none), (end position, end velocity, start position, velocity, acceleration); `_curves` the profiles
        size = bank.size
        self.curve_times, self.curve_coefficients = np.zeros((size, 2)), np.zeros((size, 2, 4))
        self.curve_knots, self.curve_ends = np.zeros(size, np.int64), np.zeros((size, 5))
        self._curves: list = [None] * size
        self._noise_of: Optional[list] = None     # the plant's batch of deviates `_noise` holds
        self._noise = np.zeros(0)
        from hil_sim.arm_tick_compiled import machine_code_for
        from host_tools.worlds.fast_loop_compiled import compiled_fast_ticks
        # the machine code for these arguments' types, called without numba's dispatcher (it types each of the
        # thirty-odd arguments at every call): `_run` passes the same types every time
        self._kernel = machine_code_for(compiled_fast_ticks(), 0, *self._arguments())
        self.calls = 0
        self.ticks_run = 0

    @staticmethod
    def fits(world) -> bool:
        """Whether `world` can have a fast loop: both its kernels compiled (`ASPOD_COMPILED=1`), its nodes handing
        each other values (a world that packs its frames runs them tick by tick: the bus path)."""
        return (world.controller.arm.bank.compiled and world.plant_node.plant._arm_tick.compiled
                and world.plant_bus.carries_values)

    def _bus_is_private(self) -> bool:
        """Only the two nodes on the bus, as the world built it, nobody logging."""
        world = self.world
        plant_bus, controller_bus = world.plant_bus, world.controller_bus
        return (world.hal_log is None and self.node.bus is plant_bus and self.hal.bus is controller_bus
                and len(plant_bus.local_channel.members) == 2
                and not ("send" in vars(plant_bus) or "send" in vars(controller_bus)))

    def _ticks_allowed(self, origin: float, period: float, n: int, ticks: int, dt: float) -> int:
        """Of `ticks` ticks, how many `fast_ticks` may run: up to the first at which the plant sends a slow frame
        (DIGITAL_IN or ANALOG_IN every so many ticks, the tracker's) or the controller's hal task CTRL_OUTPUTS,
        which ends them (`_finish`, at its time); before one at which a command holder has expired, the plant's step
        (to the nanosecond, as `PlantNode._step_length` rounds it) is not `dt`, or the batch of deviates is used
        up."""
        node, plant = self.node, self.plant
        tick = node.tick
        ticks = min(ticks, (len(plant._noise) - plant._noise_at) // 2)
        due_s = self.controller._outputs_due_s
        commanded = plant.commanded
        refreshed_s, timeout_s = commanded._refreshed_s, commanded.timeout_s
        last = node._last_now
        for k in range(ticks):
            now = origin + (n + k) * period
            if now - refreshed_s > timeout_s or round(now - last, 9) != dt:
                return k                  # CTRL_OUTPUTS expired, or a tick of another length (the plant's step)
            last = now
            t = tick + k
            if (now >= due_s or t % node.analog_every_n == 0 or t - node._digital_tick >= node.digital_every_n
                    or node.tracker and t % node.tracker_every_n == node.tracker_phase):
                return k + 1                                              # the last one
        return ticks

    def _ready(self) -> bool:
        """Nothing of the present state needs the tasks' Python: see the module docstring."""
        arm, hal, node, plant, controller = self.arm, self.hal, self.node, self.plant, self.controller
        gripper = arm.gripper
        arm_tick = self.arm_tick
        inputs = hal.inputs
        return (not arm.judge_lateness and inputs.fb_s is not None and gripper._vel_count is not None
                and [(channel.motion_id, channel.outcome) for channel in arm.channels] == arm._reported
                and controller.supervisor.outputs_allowed == controller._outputs_sent
                and node._last_switches is not None and node._last_now is not None
                and plant.motor_commands._last_alive != hal.motor_alive
                and plant.commanded._refreshed_s is not None
                and arm_tick._arm.load_model() is arm_tick._model
                and arm_tick._motors.state_writes == arm_tick._sampled_writes)

    def run(self, origin: float, period: float, n: int, ticks: int) -> int:
        first = origin + n * period
        node, plant = self.node, self.plant
        if not self._bus_is_private():
            return 0
        # What waits on the bus is read now, at the first tick's time, as each node's first poll in it would read
        # it (the arm task's, the plant task's: they read the same frames at the same time; what the tick sends
        # comes after them, and each frame's handler changes its own things only).
        if self.world.controller_bus.pending:
            self.hal.poll(first)
        if self.world.plant_bus.pending:
            node.poll(first)
        if not self._ready():
            return 0
        dt = node._rounded_steps.get(first - node._last_now)
        if dt is None:
            dt = round(first - node._last_now, 9)
        if not 0.0 < dt <= node.max_dt_s or dt != self.arm_tick._dt_s or dt != plant._decay_dt_s:
            return 0
        ticks = self._ticks_allowed(origin, period, n, ticks, dt)
        if ticks <= 0:
            return 0
        ran = self._run(origin, period, n, ticks, dt)
        self.calls += 1
        self.ticks_run += ran
        return ran

    def _run(self, origin: float, period: float, n: int, ticks: int, dt: float) -> int:
        arm, hal, node, plant, bank, arm_tick = self.arm, self.hal, self.node, self.plant, self.bank, self.arm_tick
        gripper, inputs, p, params = arm.gripper, hal.inputs, plant.params, arm.params
        enabled, brake_all = plant.commanded._commanded
        lo, hi = node._current_range_a
        self._pack_floats(self.f, 0, origin, period, inputs.fb_s, params["gravity_m_s2"], params["payload_kg"],
                          hal.duty_step, gripper.hold_duty, gripper._ref_m, gripper._m_per_count, gripper.vel_m_s,
                          gripper._vel_s, gripper.opening_m, gripper.duty, arm_tick._h_s, plant.supply_true_v,
                          plant.temp_true_c, plant.current_a, plant._supply_v, plant._temp_c, arm_tick.bridges_a,
                          plant._decay, plant.supply_emf_v, plant.ambient_c, p.idle_current_a, p.enabled_current_a,
                          p.supply_source_ohm, p.drive_on_resistance_ohm, p.thermal_resistance_c_per_w,
                          p.supply_noise_v, p.temp_noise_c, lo, hi, self.current_scale, dt, node._tracker_dt,
                          gripper._started_s, gripper._still_since, gripper.grip_current_a, gripper.grip_duty,
                          gripper.timeout_s)
        mode = gripper.mode
        self._pack_ints(self.i, 0, n, hal.motor_alive, node.tick, plant._noise_at, gripper._ref_count,
                        gripper._vel_count, gripper.gripped, mode is AxisMode.HOLDING, arm.outputs_allowed, enabled,
                        brake_all, arm_tick._substeps, bank.size, node.tracker, mode is AxisMode.MOVING,
                        gripper._direction, gripper._last_count, inputs.limit_lo[GRIPPER_INDEX],
                        inputs.limit_hi[GRIPPER_INDEX], False, GRIPPER_INDEX, 0)
        self.counts_in[:] = inputs.counts
        self.currents_in[:] = inputs.currents_a
        self.home[:] = inputs.home
        self.switches_sent[:] = node._last_switches
        brakes = [channel.brake for channel in arm.channels]
        self.brakes[:] = brakes
        self._load_curves()
        if plant._noise is not self._noise_of:          # a new batch of deviates: as an array once
            self._noise_of, self._noise = plant._noise, np.asarray(plant._noise, dtype=np.float64)
        ran = self._kernel(ticks, *self._arguments())
        if ran:
            last = origin + (n + ran - 1) * period
            self._hand_back(ran, last, brakes)
            self._finish(last)
        return ran

    def _finish(self, last: float) -> None:
        """The rest of the last tick, in the tasks' code: the plant's slow frames, the hal task's reading them and its
        CTRL_OUTPUTS (each does nothing when nothing is due). The switches are as last sent but after an edge."""
        node = self.node
        sent = node.frames_sent
        node.send_slow(node.tick - 1, last, self.plant.switches() if self.i[I_EDGE] else node._last_switches)
        if node.frames_sent != sent:
            self.hal.poll(last)
        self.controller.send_outputs(last)

    def _load_curves(self) -> None:
        """Each joint's trajectory curve into the curve rows, when its profile has changed."""
        profiles, curves = self.bank.profiles, self._curves
        for k, profile in enumerate(profiles):
            if profile is curves[k]:
                continue
            curves[k] = profile
            if not isinstance(profile, HermiteProfile):
                self.curve_knots[k] = 0
                continue
            knots = len(profile.times_s)
            if knots > self.curve_times.shape[1]:                 # room for it: the rows grow
                size = len(profiles)
                times, coefficients = np.zeros((size, knots)), np.zeros((size, knots, 4))
                times[:, :self.curve_times.shape[1]] = self.curve_times
                coefficients[:, :self.curve_coefficients.shape[1]] = self.curve_coefficients
                self.curve_times, self.curve_coefficients = times, coefficients
            self.curve_times[k, :knots] = profile.times_s
            self.curve_coefficients[k, :knots - 1] = profile.coefficients
            self.curve_knots[k] = knots
            self.curve_ends[k] = (profile.end_pos_rad, profile.end_vel_rad_s, *profile.sample(0.0))

    def _arguments(self) -> tuple:
        """`fast_ticks`'s arguments after `ticks`."""
        bank, arm_tick = self.bank, self.arm_tick
        return (self.f, self.i, bank.masses, self.counts_in, self.currents_in, self.home, self.switches_sent,
                self.brakes, self._noise, self.values, self.curve_times, self.curve_coefficients, self.curve_knots,
                self.curve_ends, bank.state, bank.int_state, bank.config, bank.int_config,
                bank.profile, bank.gravity_nm, bank.duties, arm_tick.command, arm_tick.state, arm_tick.table,
                arm_tick.flags, arm_tick.counts, arm_tick.constants, *self._saved)

    def _hand_back(self, ran: int, last: float, brakes: list) -> None:
        """The Python state the tasks keep, as `ran` ticks ending at `last` leave it."""
        arm, hal, node, plant, arm_tick = self.arm, self.hal, self.node, self.plant, self.arm_tick
        gripper, inputs = arm.gripper, hal.inputs
        f, i = self._unpack_floats(self.f), self._unpack_ints(self.i)    # Python floats and ints
        n = len(arm.channels)
        # arm
        arm._last_tick_s = last
        self.bank.handed_back += i[I_HANDED]
        gripper.opening_m, gripper.vel_m_s, gripper._vel_s = f[F_OPENING_M], f[F_VEL_M_S], f[F_VEL_S]
        gripper._vel_count, gripper.duty = i[I_VEL_COUNT], f[F_GRIP_DUTY]
        gripper._still_since, gripper._last_count = f[F_STILL_SINCE], i[I_LAST_COUNT]
        if arm.outputs_allowed:
            flags = hal._motor_flags([not b for b in brakes], brakes)
        else:
            flags = hal._motor_flags([False] * n, [True] * n)
        command = self.values[:n].tolist() + flags        # as MOTOR_CMD carries them: the flags 0/1 (as the kernel's)
        alive = i[I_ALIVE]
        hal.motor_alive = alive
        hal.frames_sent += ran
        sent = hal.sent_by_name
        sent["MOTOR_CMD"] = sent.get("MOTOR_CMD", 0) + ran
        hal.frames_received += 2 * ran
        inputs.counts, inputs.currents_a = self.counts_in.tolist(), self.currents_in.tolist()
        inputs.fb_s = inputs.tick_s = last
        inputs.tick = (i[I_NODE_TICK] - 1) & 0xFFFF_FFFF
        # plant
        holder = plant.motor_commands
        holder._last_alive, holder._commanded, holder._refreshed_s = (alive - 1) & 0xFF, command, last
        holder.expired = plant.commanded.expired = False
        plant.outputs_enabled, plant.brake = i[I_OUTPUTS_ENABLED] != 0, i[I_BRAKE_ALL] != 0    # as `Plant.tick` sets
        plant.current_a, plant.supply_true_v, plant.temp_true_c = f[F_CURRENT_A], f[F_SUPPLY_TRUE_V], f[F_TEMP_TRUE_C]
        plant._supply_v, plant._temp_c, plant._noise_at = f[F_SUPPLY_V], f[F_TEMP_C], i[I_NOISE_AT]
        arm_tick._given, arm_tick.bridges_a, arm_tick._flags_out = command, f[F_BRIDGES_A], None
        node.tick, node._last_now, node._tracker_dt = i[I_NODE_TICK], last, f[F_TRACKER_DT]
        node.frames_received += ran
        node.frames_sent += 2 * ran
        sent = node.sent_by_name
        sent["MOTOR_FB"] = sent.get("MOTOR_FB", 0) + ran
        sent["PLANT_SYNC"] = sent.get("PLANT_SYNC", 0) + ran
