"""The world's fast loop (host_tools/worlds/fast_loop.py): the 1 kHz tasks many ticks a call, the same to the bit.

Each world runs twice, compiled, with and without the fast loop: every byte on the link either way (with its time),
every telemetry frame and event the host got, the plant's and the controller's state, the endpoints' counters and
the scheduler's statistics must come out the same. Needs numba (the fast loop is the compiled world's)."""
from __future__ import annotations

import numpy as np
import pytest

import kernels
from host_tools.apps import pick_place
from host_tools.outputs import Output
from host_tools.worlds.can_log import KINDS
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M
from protocol.states import Axis, GripAction

pytest.importorskip("numba")


def _world(fast: bool, **kwargs) -> tuple[LockstepBench, list]:
    line: list = []

    def taps(direction):
        def tap(data: bytes) -> bytes:
            line.append((direction, bench.clock.now(), bytes(data)))
            return data
        return tap
    with kernels.switched(True):
        bench = LockstepBench(seed=3, fast_loop=fast, to_controller=taps("in"), to_host=taps("out"), **kwargs)
    return bench, line


def _everything(bench: LockstepBench, line: list) -> dict:
    """All a run left that the fast loop could change."""
    world, controller = bench.world, bench.controller
    node, hal, plant = world.plant_node, controller.hal, world.plant
    gripper = controller.arm.gripper
    return {
        "line": line,
        "telemetry": [repr(m) for m in bench.telemetry],
        "events": [repr(m) for m in bench.events],
        "joints": [controller.arm.bank.state.tobytes(), controller.arm.bank.int_state.tobytes()],
        "plant arm": [plant._arm_tick.state.tobytes(), plant._arm_tick.flags.tobytes(),
                      plant._arm_tick.counts.tobytes()],
        "plant": repr((plant.supply_v, plant.temp_c, plant.current_a, plant.temp_true_c, plant._noise_at,
                       plant.outputs_enabled, plant.brake,
                  plant.motor_commands.current_values(bench.clock.now()), plant.commanded.current(bench.clock.now()))),
        "gripper": repr((gripper.opening_m, gripper.vel_m_s, gripper.duty, gripper.mode, gripper._still_since,
                         gripper._last_count)),                       # (NaN as its repr: never equal to itself)
        "hal inputs": repr(hal.inputs),
        "counters": (node.frames_sent, node.frames_received, sorted(node.sent_by_name.items()), hal.frames_sent,
                     hal.frames_received, sorted(hal.sent_by_name.items()), hal.motor_alive, hal.alive, node.tick),
        "tasks": {name: (task.stats.runs, task.stats.late_max_s, task.stats.overruns, task.wake_s, task.grid_n)
                  for name, task in world.scheduler.tasks.items()},
        "time": bench.clock.now(),
    }


def _differences(a: dict, b: dict) -> list[str]:
    return [key for key in a if a[key] != b[key]]


def _moving(bench: LockstepBench, seconds: float) -> None:
    """The lock-step bench's moving world: jogs on every joint and the mount, the gripper closing and opening."""
    assert bench.connect()
    assert bench.call(M["SetTelemetryRate"](20)).ok and bench.call(M["Enable"]()).ok
    sign = 1
    for _ in range(int(seconds / 2.5)):
        now = bench.clock.now()
        for axis in (Axis.J1, Axis.J2, Axis.J3, Axis.J4, Axis.MOUNT):
            bench.host.submit(M["Jog"](int(axis), sign * 2.0), now)
        bench.host.submit(M["Grip"](int(GripAction.CLOSE if sign > 0 else GripAction.OPEN)), now)
        sign = -sign
        bench.run_for(2.5)


def test_the_moving_world_is_the_same_to_the_bit_and_most_of_its_ticks_run_fast():
    runs = []
    for fast in (False, True):
        bench, line = _world(fast)
        _moving(bench, 10.0)
        runs.append(_everything(bench, line))
        loop = bench.world.fast_loop
        if fast:
            ticks = bench.world.scheduler.tasks["arm"].stats.runs
            assert loop is not None and loop.ticks_run > ticks / 2, (loop.ticks_run, ticks)
        else:
            assert loop is None
        bench.close()
    assert len(runs[0]["telemetry"]) > 150 and len(runs[0]["line"]) > 300
    assert not _differences(*runs)


def test_the_pick_and_place_homing_moves_trajectories_and_grips_are_the_same_to_the_bit():
    runs = []
    for fast in (False, True):
        bench, line = _world(fast)
        demo = pick_place.PickAndPlace.on_bench(bench)
        demo.prepare()
        results = [demo.run_step(step).as_dict() for step in pick_place.steps(demo.scene)]
        runs.append((results, _everything(bench, line)))
        if fast:
            assert bench.world.fast_loop.ticks_run > 0.5 * bench.world.scheduler.tasks["arm"].stats.runs
        bench.close()
    (a, state_a), (b, state_b) = runs
    assert len(a) >= 10 and a == b
    assert not _differences(state_a, state_b)


@pytest.mark.parametrize("fault, channel", [("jam", "j2"), ("encoder_dropout", "j1"), ("open_circuit", "j3"),
                                            ("supply_sag", None), ("stuck_brake", "mount")])
def test_a_fault_injected_mid_run_is_met_at_the_same_tick(fault, channel):
    runs = []
    for fast in (False, True):
        bench, line = _world(fast)
        _moving(bench, 2.5)
        bench.world.plant.inject(fault, channel)
        _moving_on = bench.clock.now()
        bench.run_for(2.0)
        assert bench.clock.now() > _moving_on
        runs.append(_everything(bench, line))
        bench.close()
    assert any("FaultReport" in e or "StateChanged" in e for e in runs[0]["events"][-6:]) or fault == "stuck_brake"
    assert not _differences(*runs)


def test_the_fast_loop_stands_aside_while_a_hal_log_looks_at_the_bus(tmp_path):
    bench, _ = _world(True)
    _moving(bench, 2.5)
    loop = bench.world.fast_loop
    before = loop.ticks_run
    log = bench.world.log_hal_bus(Output(tmp_path / "hal.asc", "--can-log", KINDS[".asc"]))
    bench.run_for(0.5)
    assert loop.ticks_run == before               # every frame on the bus, for the log
    assert log.frames >= 3 * 500                  # MOTOR_CMD, MOTOR_FB, PLANT_SYNC a tick at least
    bench.close()


def test_motor_fb_currents_as_the_kernel_rounds_them_are_what_the_bus_carries():
    """`fast_ticks` rounds MOTOR_FB's currents itself (half to even on the signal's scale): the layout's round trip
    over the whole range, and the steps' halves, agree."""
    bench, _ = _world(True)
    node = bench.world.plant_node
    layout, loop = node._motor_fb, bench.world.fast_loop
    scale, rounding = loop.current_scale, 6755399441055744.0
    rng = np.random.default_rng(1)
    values = list(rng.uniform(-32.768, 32.767, 20000)) + [(k + 0.5) * scale for k in range(-32768, 32767, 7)]
    for v in values:
        carried = layout.roundtrip([0, 0, 0, 0, 0, 0, 0, v, 0.0, 0.0, 0.0, 0.0, 0.0])[7]
        assert (v / scale + rounding - rounding) * scale == carried, v
    bench.close()


def test_what_the_plant_applied_is_the_same_every_millisecond_after_a_disable():
    """`Plant.outputs_enabled` and `brake` are set by each tick the plant takes: a review found the fast loop left
    them as they were for up to 9 ms after CTRL_OUTPUTS changed, where a bench waiting on them reads them."""
    traces = []
    for fast in (False, True):
        bench, _ = _world(fast)
        assert bench.connect() and bench.call(M["Enable"]()).ok
        bench.run_for(0.05)
        plant = bench.world.plant
        bench.host.submit(M["Disable"](), bench.clock.now())
        trace = []
        for _ in range(40):
            bench.run_for(0.001)
            trace.append((bench.clock.now(), plant.outputs_enabled, plant.brake, plant.commanded._commanded))
        traces.append(trace)
        bench.close()
    assert traces[0] == traces[1]
    assert traces[0][0][1] and not traces[0][-1][1]           # it was enabled, and the disable reached the plant
