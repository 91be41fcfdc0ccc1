"""The world one bench run happens in, as one frozen value: seed, plant, faults at their times, the link's
impairment, controller parameters.

`aspod bench`, the pytest plugin's lock-step target and `aspod campaign` all build their world from a
`WorldSettings` (`build_bench`), and each turns one back into its own command line (`to_bench_argv`,
`to_pytest_argv`), so a campaign's row carries the one command that runs it again alone.

A timed fault is written `NAME[:CHANNEL]@AT[-UNTIL]` in simulated seconds from the world's start:
`jam:j2@3.5` (injected at 3.5 s, never cleared), `supply_sag@10-12` (cleared at 12 s). Injections
go through the plant's actions (`LockstepBench.act("inject", ...)`), so a recorded session keeps
them as world events and `aspod replay` does them again.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from hil_sim.faults import fault_key, resolve

from host_tools.sessions.impairment import Impairment
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import AFTER_THE_WORLD, LockstepBench

NO_FAULT = "none"       # a campaign's fault axis: a run without one


@dataclass(frozen=True)
class TimedFault:
    """A plant fault (its key, as `Plant.faults` lists it: "jam:j2") injected at `at_s` and cleared at
    `until_s` (None: never), in simulated seconds from the world's start."""
    fault: str
    at_s: float
    until_s: Optional[float] = None

    def __post_init__(self) -> None:
        spec, index = resolve(self.fault)       # ValueError naming the known faults and channels
        object.__setattr__(self, "fault", fault_key(spec, index))
        if not (isinstance(self.at_s, (int, float)) and math.isfinite(self.at_s) and self.at_s >= 0):
            raise ValueError(f"fault {self.fault}: its time must be a finite number of seconds >= 0, "
                             f"got {self.at_s!r}")
        if self.until_s is not None and not (isinstance(self.until_s, (int, float)) and math.isfinite(self.until_s)
                                             and self.until_s > self.at_s):
            raise ValueError(f"fault {self.fault}: it must be cleared after it is injected ({self.at_s:g} s), "
                             f"got {self.until_s!r}")

    @classmethod
    def parse(cls, text: str) -> "TimedFault":
        """`NAME[:CHANNEL]@AT[-UNTIL]`: `jam:j2@3.5`, `supply_sag@10-12`. ValueError saying what is wrong."""
        name, sep, when = text.strip().partition("@")
        if not sep or not name:
            raise ValueError(f"fault {text!r}: write NAME[:CHANNEL]@SECONDS, e.g. jam:j2@3.5 or supply_sag@10-12")
        at, dash, until = when.partition("-")
        try:
            at_s = float(at)
            until_s = float(until) if dash else None
        except ValueError:
            raise ValueError(f"fault {text!r}: {when!r} is not SECONDS or SECONDS-SECONDS") from None
        return cls(name, at_s, until_s)

    def __str__(self) -> str:
        return f"{self.fault}@{self.at_s:g}" + ("" if self.until_s is None else f"-{self.until_s:g}")


@dataclass(frozen=True)
class WorldSettings:
    """Everything that makes one lock-step run what it is; the same value gives the same run, to the bit."""
    seed: int = 0
    plant: PlantSettings = PlantSettings()
    faults: tuple[TimedFault, ...] = ()
    impairment: Optional[str] = None                 # an `Impairment.parse` spec: "radio", "ber=1e-5,drop=0.01"
    params: tuple[tuple[str, float], ...] = ()       # controller parameters set before the run (each arm's)
    arms: int = 1                                    # 2: the report's two example arms and their object

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be a whole number >= 0, got {self.seed!r}")
        object.__setattr__(self, "faults", tuple(self.faults))
        object.__setattr__(self, "params", tuple((str(k), float(v)) for k, v in self.params))
        if self.impairment is not None:
            Impairment.parse(self.impairment)        # ValueError now rather than when the world is built
        if self.arms not in (1, 2):
            raise ValueError(f"arms is 1 or 2, not {self.arms!r}")

    def to_bench_argv(self) -> list[str]:
        """These settings as `aspod bench` takes them."""
        argv = ["--seed", str(self.seed), *self.plant.to_argv()]
        for fault in self.faults:
            argv += ["--fault", str(fault)]
        if self.impairment is not None:
            argv += ["--impairment", self.impairment]
        for name, value in self.params:
            argv += ["--param", f"{name}={value!r}"]
        if self.arms != 1:
            argv += ["--arms", str(self.arms)]
        return argv

    def to_pytest_argv(self) -> list[str]:
        """These settings as the pytest plugin takes them (each `--aspod-option=value`, one token: see
        docs/benches.md for why)."""
        argv, flags = [], self.to_bench_argv()
        i = 0
        while i < len(flags):
            flag = flags[i]
            if i + 1 < len(flags) and not flags[i + 1].startswith("--"):
                argv.append(f"--aspod-{flag[2:]}={flags[i + 1]}")
                i += 2
            else:
                argv.append(f"--aspod-{flag[2:]}")
                i += 1
        return argv


def apply_params(bench: LockstepBench, params) -> None:
    """Set controller parameters by name before a run (in passes, as a parameter file is loaded), each arm's
    controller's; ValueError naming the first one refused (then some of the others may be set: build the bench
    again)."""
    controllers = [bench.controller] + ([bench.world.arm2.controller] if bench.world.arm2 is not None else [])
    for controller in controllers:
        refused = controller.params.set_all(params)
        if refused:
            raise ValueError(f"parameter {next(iter(refused.values()))}")
        controller.telemetry_hz = int(controller.params["telemetry_hz"])


def schedule_faults(bench: LockstepBench, faults: tuple[TimedFault, ...]) -> None:
    """Inject and clear each fault at its simulated time, through the bench's plant actions."""
    due = sorted([(f.at_s, "inject", f.fault) for f in faults]
                 + [(f.until_s, "clear", f.fault) for f in faults if f.until_s is not None])
    if not due:
        return

    def step(now: float) -> float:
        while due and due[0][0] <= now:
            _, action, fault = due.pop(0)
            bench.act(action, fault)
        return due[0][0] if due else math.inf
    # after the world's tasks at the same moment, as a world event is done (and replayed: apps/replay.py)
    bench.world.scheduler.add("timed-faults", step, first_wake_s=due[0][0], priority=AFTER_THE_WORLD)


def build_bench(world: WorldSettings, **bench_options) -> LockstepBench:
    """A `LockstepBench` as `world` says (its faults scheduled); `bench_options` go to `LockstepBench`.
    ValueError if a parameter is refused."""
    impairment = None if world.impairment is None else Impairment.parse(world.impairment)
    if world.arms == 2:
        bench_options = {**two_arm_options(), **bench_options}
    bench = LockstepBench(seed=world.seed, plant=world.plant, impairment=impairment, **bench_options)
    try:
        apply_params(bench, world.params)
    except ValueError:
        bench.close()
        raise
    schedule_faults(bench, world.faults)
    return bench


def two_arm_options() -> dict:
    """A lock-step world's two arms as `aspod sim --arms 2` has them (docs/two_arms.md): two example arms, the
    example's object waiting on its stand at its path's start until both jaws close on it."""
    from firmware_py.arm_config import EXAMPLE_ARM
    from firmware_py.controller import ControllerConfig
    from hil_sim.arm_params import EXAMPLE_ARM_PLANT
    from hil_sim.held_object import ObjectParams
    from host_tools.plan.example import PATH
    return dict(arms=2, controller_config=ControllerConfig(arm=EXAMPLE_ARM), arm_params=EXAMPLE_ARM_PLANT,
                held_object=ObjectParams(), object_waits_at_m=PATH[0])
