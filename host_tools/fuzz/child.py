"""One in-process fuzzing job: atheris (libFuzzer) driving one target, in a process of its own.

    python -m host_tools.fuzz.child TARGET FINDINGS_DIR HANG_S [libFuzzer options and corpus folders]

libFuzzer owns the process it runs in (it exits when done or on a finding), so `aspod fuzz` runs it here and reads
its progress lines; the target's own libFuzzer options (`engine_options`) come before those given here. Nothing of
the emulator is imported before atheris' import hook is in place, so the code under test is instrumented for
coverage. On a crash or an oracle failure the finding is written to FINDINGS_DIR with every input since the target
was last fresh (host_tools/fuzz/findings.py) before libFuzzer reports it. An input past HANG_S seconds of its own
time (not counting the time the host kept it waiting for a CPU: host_tools/fuzz/hangs.py) is interrupted and saved
the same way, as a hang. Running out of memory, or a hang the interrupt cannot reach, is left to libFuzzer's own
artifact, which `aspod fuzz` turns into a finding.
"""
import importlib
import importlib.util
import sys
from pathlib import Path

from timebase import RealClock

import atheris

from host_tools.fuzz.hangs import Hang, HangWatch

_CLOCK = RealClock()           # the wall clock (timebase: the one module that reads it)

PROGRESS_EVERY_S = 1.0       # how often the job says how many inputs it has run (libFuzzer's own lines thin out)

# the code under test; the plant, the clock and the worlds that carry it are not (their coverage would only
# slow every execution down, and count the plant's branches as the target's)
INSTRUMENTED = ["protocol", "firmware_py", "hil_sim.hal_node", "host_tools.teleop", "host_tools.fuzz.planted"]

# The 1 kHz loops and the HAL bus between the controller and the plant: every simulated millisecond of a link
# target's world runs them, and no frame on the link is decided there. Instrumented (until 2026-11-28) they cost
# controller-link half its time (1,984 against 1,012 us an input, the same inputs), kept in its corpus inputs that
# only let time pass, and, with ASPOD_COMPILED=1, killed the child: numba cannot compile the joints' kernel from
# instrumented bytecode. Only `hal`, the target of the HAL decoders, instruments them (they are what it covers).
FAST_LOOP = ["firmware_py.joints_tick", "firmware_py.joint_bank", "firmware_py.joints_compiled", "firmware_py.hal",
             "firmware_py.gripper_tick", "firmware_py.estimator", "firmware_py.hermite", "protocol.hal",
             "protocol.frame_code", "protocol.value_frame", "hil_sim.hal_node"]


def _under(module: str, names) -> bool:
    return any(module == n or module.startswith(n + ".") for n in names)


def modules_not_under_test(instrumented: list[str]) -> list[str]:
    """Every module of `instrumented`'s top-level packages that is not itself named there (or inside one named).
    atheris' `include` keeps only a name's top-level package (what comes before the first dot), so until
    2026-11-27 `hil_sim.hal_node` instrumented all of hil_sim, the plant included, and `host_tools.teleop` all of
    host_tools: the worlds, the sessions, this harness and its grammar. Its `exclude` takes whole module names,
    so they are listed here, from the files (nothing is imported: a module imported before the hook would run
    uninstrumented)."""
    out = []
    for top in sorted({name.split(".")[0] for name in instrumented}):
        spec = importlib.util.find_spec(top)
        if spec is None or not spec.submodule_search_locations:
            continue
        for root in spec.submodule_search_locations:
            for path in sorted(Path(root).rglob("*.py")):
                parts = [top, *path.relative_to(root).with_suffix("").parts]
                if parts[-1] == "__init__":
                    parts.pop()
                module = ".".join(parts)
                if not _under(module, instrumented) and not any(n.startswith(module + ".") for n in instrumented):
                    out.append(module)
    return out


def instrumenting(spec: str):
    """atheris' import hook for the target `spec`: the code under test, nothing else of ours (nor the fast loop,
    but for `hal`). For your own target (`module:factory`): the whole package its module is in (its top-level
    package, as atheris takes it, where that is not one of ours)."""
    from host_tools.fuzz.own import own_module         # (the standard library only: nothing under test yet)
    module = own_module(spec) if ":" in spec else None
    own = [module.rpartition(".")[0] or module] if module else []
    exclude = [m for m in modules_not_under_test(INSTRUMENTED) if not _under(m, own)]
    if spec != "hal":
        exclude += FAST_LOOP
    return atheris.instrument_imports(include=INSTRUMENTED + [module] * bool(module), exclude=exclude)


class Harness:
    """Calls the target, rebuilding a stateful one every `fresh_every` inputs, and keeps the inputs since."""

    def __init__(self, target, spec: str, findings, watch) -> None:
        self.target, self.spec, self.findings, self.watch = target, spec, findings, watch
        self.stateful = getattr(target, "stateful", False)
        self.fresh_every = getattr(target, "fresh_every", 1)
        self.history: list[bytes] = []
        self.execs = 0
        self._said_s = _CLOCK.now()

    def __call__(self, data: bytes) -> None:
        if self.stateful and self.execs % self.fresh_every == 0:
            try:
                self.target.fresh()   # (which closes the world the last inputs left: that may fail on their state)
            except Exception as exc:
                if not self.history:
                    raise                   # no input ran: the target cannot be built, no finding
                self.save(exc, self.history)
                raise
            self.history.clear()
        self.execs += 1
        if self.execs & 255 == 0 and _CLOCK.now() - self._said_s >= PROGRESS_EVERY_S:
            self._said_s = _CLOCK.now()
            print(f"ASPOD-PROGRESS {self.execs}", file=sys.stderr, flush=True)
        if self.stateful:
            self.history.append(bytes(data))
        try:
            with self.watch.input():
                self.target.one_input(data)
        except (Exception, Hang) as exc:
            self.save(exc, self.history if self.stateful else [bytes(data)])
            raise

    def save(self, exc: BaseException, inputs: list[bytes]) -> None:
        from host_tools.fuzz import findings
        finding = findings.Finding(self.spec, findings.failure_of(exc), list(inputs), execs=self.execs)
        path = finding.save(self.findings)
        print(f"ASPOD-FINDING {path}", file=sys.stderr, flush=True)


def load_for_fuzzing(spec: str):
    """The target, with every module it runs imported now, so that the caller's import hook instruments them: the
    files it covers (`Target.covers`) and, for a stateful target, what `fresh` builds. A module first imported
    later runs uninstrumented and libFuzzer is blind to its branches: so it was, until 2026-11-25, for the
    controller and protocol/controller_link.py (controller-link), protocol/host_link.py (host-link) and the HAL
    decoders (hal), whose worlds were first built by the harness's first `fresh`."""
    from host_tools.fuzz.targets import load_target
    target = load_target(spec)
    for path in getattr(target, "covers", ()):
        importlib.import_module(path.removesuffix(".py").replace("/", "."))
    if getattr(target, "stateful", False):
        target.fresh()
    return target


def main(argv: list[str]) -> None:
    spec, findings_dir, hang_s, libfuzzer_args = argv[0], Path(argv[1]), float(argv[2]), argv[3:]
    with instrumenting(spec):
        target = load_for_fuzzing(spec)
    with HangWatch(hang_s) as watch:
        harness = Harness(target, spec, findings_dir, watch)
        atheris.Setup([sys.argv[0], *getattr(target, "engine_options", ()), *libfuzzer_args], harness)
        atheris.Fuzz()


if __name__ == "__main__":
    main(sys.argv[1:])
