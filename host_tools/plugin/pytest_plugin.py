"""The pytest plugin installed with the package (entry point `pytest11`: `aspod`): any project's tests get a bench
target, and teleop scripts named `*.aspod` are collected as tests. See docs/benches.md.

Options:
    --aspod-target URL     a live controller (`aspod sim`'s pty or TCP port, or real hardware) instead of the default
                           lock-step world on the simulated clock
    --aspod-key-file FILE  its key (default: that of the local simulator serving URL, as its endpoint says)
    --aspod-control PATH   a live `aspod sim`'s control endpoint, to fault and read its plant (default: the one
                           found beside --aspod-target, if any; real hardware has none)
    --aspod-seed N         the lock-step world's seed (default 1)
    --aspod-json DIR       a JSON record per test: outcome, target, measurements, a script's steps

Fixture `aspod_target` (host_tools/plugin/target.py): connected, closed after the test. A test that needs
the plant (faults, actions, its true state; pausing its time) is skipped on a target that has none to offer
(real hardware, a live simulator without its control endpoint), with the reason, never faked. `aspod_target.measure(name, value, unit)` keeps a figure for the test's record and
its JUnit properties.

A `*.aspod` file is a teleop script: one test, each line a step in its report. Its first line may say
what world it needs, as `aspod bench` takes it: `#! aspod bench --sun-start 2026-03-20T06:50-07:00 --seed 3`.
"""
from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import pytest

from host_tools.plugin.errors import CannotFault

# The plugin loads in every pytest run of any project that installs the package: what it needs of the
# emulator (the worlds, the clients, numba perhaps) is imported when a bench asks for a target, not before.

SCRIPT_SUFFIX = ".aspod"
RECORD_KEY = pytest.StashKey[dict]()


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("aspod", "ASPOD controller benches")
    group.addoption("--aspod-target", default=None, metavar="URL",
                    help="run benches against a live controller at URL (default: the lock-step world)")
    group.addoption("--aspod-key-file", default=None, metavar="FILE",
                    help="the live controller's key file (default: that of the local simulator serving --aspod-target)")
    group.addoption("--aspod-control", default=None, metavar="PATH",
                    help="the live simulator's control endpoint (default: the aspod sim's found beside --aspod-target)")
    group.addoption("--aspod-json", default=None, metavar="DIR", help="write a JSON record per test into DIR")
    group.addoption("--aspod-seed", default=None, metavar="N", help="the lock-step world's seed (default 1)")
    for option, metavar, what in WORLD_OPTIONS:
        group.addoption(f"--aspod-{option}", default=None, metavar=metavar, help=f"the lock-step world's {what}")
    for option, metavar, what in WORLD_LISTS:
        group.addoption(f"--aspod-{option}", action="append", default=[], metavar=metavar, help=what)
    group.addoption("--aspod-no-tracker", action="store_true", help="the lock-step world's plant without the tracker")


# The lock-step world's settings, as `aspod bench` takes them (host_tools/worlds/bench_world.py), each
# `--aspod-<its name>`: one grammar, one parser, one set of checks for both.
WORLD_OPTIONS = (("gravity", "earth|orbit", "gravity"), ("payload-kg", "M", "payload at the gripper, kg"),
                 ("sun-start", "ISO", "sun's start (default: a fixed date, as aspod bench)"),
                 ("clouds", "SPEC", "clouds over the tracker"), ("impairment", "SPEC", "link impairment (radio, ...)"),
                 ("arms", "1|2", "arms: 2, the report's two example arms and their object (aspod_target.arm2)"))
WORLD_LISTS = (("fault", "NAME[:CH]@T", "a plant fault at simulated time T (repeatable): jam:j2@3.5"),
               ("param", "NAME=VALUE", "a controller parameter set before the test (repeatable)"),
               ("var", "NAME=VALUE", "a bench variable: aspod_target.variables[NAME], a script's ${NAME} (repeatable)"))
DEFAULT_SEED = "1"
WORLD_BUILT = {f"--{option}" for option, _, _ in WORLD_OPTIONS} | {"--fault", "--param", "--no-tracker"}


def world_asked(directive: tuple[str, ...]) -> list[str]:
    """The options of a script's directive that build the world (not the seed, which is only the lock-step world's
    randomness, nor the variables): what a live target, built elsewhere, cannot be given."""
    asked, words = [], list(directive)
    for k, word in enumerate(words):
        if word.split("=", 1)[0] in WORLD_BUILT:
            asked.append(word)
            if "=" not in word and word != "--no-tracker" and k + 1 < len(words):
                asked.append(words[k + 1])
    return asked


def pytest_configure(config: pytest.Config) -> None:
    """Bad --aspod options are the run's usage error, said once before anything is collected (pytest's exit
    status 4), not an error in every test that asks for a target. Without them the plugin imports nothing more."""
    lists = [option for option, _, _ in WORLD_LISTS]
    given = [name for name in ("target", "seed", *(option for option, _, _ in WORLD_OPTIONS))
             if config.getoption(f"--aspod-{name}", None) is not None]
    given += [name for name in (*lists, "no-tracker") if config.getoption(f"--aspod-{name}", None)]
    if not given:
        return
    world_and_variables(config)
    url = config.getoption("--aspod-target")
    if url is not None:
        from host_tools.client.lines import parse_links
        try:
            parse_links(url)
        except ValueError as exc:
            raise pytest.UsageError(f"--aspod-target: {exc}") from None


def bench_options(config: pytest.Config, directive: tuple[str, ...] = ()) -> tuple[list[str], list[str]]:
    """The world's `aspod bench` options: the seed's default, a script's directive, then this run's options
    (which win); and the variables (`--var` pairs)."""
    argv = ["--seed", DEFAULT_SEED, *directive]
    seed = config.getoption("--aspod-seed")
    if seed is not None:
        argv += ["--seed", seed]
    for option, _, _ in WORLD_OPTIONS:
        value = config.getoption(f"--aspod-{option}")
        if value is not None:
            argv += [f"--{option}", value]
    for option in ("fault", "param"):
        for value in config.getoption(f"--aspod-{option}"):
            argv += [f"--{option}", value]
    if config.getoption("--aspod-no-tracker"):
        argv.append("--no-tracker")
    return argv, list(config.getoption("--aspod-var"))


def world_and_variables(config: pytest.Config, directive: tuple[str, ...] = (), where: str = "--aspod options"):
    """(WorldSettings, variables) from the run's options (and a script's directive); pytest.UsageError saying
    what does not parse."""
    from host_tools.cli.main import build_parser
    from host_tools.cli.settings import bench_settings
    argv, variables = bench_options(config, directive)
    argv += [x for pair in variables for x in ("--var", pair)]
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said):        # argparse's usage is `aspod bench`'s, not this run's
            args = build_parser(["bench"]).parse_args(["bench", "-", *argv])
        settings = bench_settings(args)
    except SystemExit:
        why = said.getvalue().strip().splitlines()[-1:] or ["they do not parse"]
        raise pytest.UsageError(f"{where}: {why[0].split('error: ', 1)[-1]} (as aspod bench takes it: "
                                "--aspod-NAME here is its --NAME)") from None
    except ValueError as exc:
        raise pytest.UsageError(f"{where}: {exc}") from None
    return settings.world, dict(settings.variables)


def make_target(config: pytest.Config, directive: tuple[str, ...] = (), where: str = "--aspod options"):
    """The target the run asks for: the lock-step world its options (and a script's directive) describe, or the
    live controller of --aspod-target."""
    from protocol import auth
    from host_tools.client.control import simulator_key
    from host_tools.plugin.target import LiveTarget, LockstepTarget
    url = config.getoption("--aspod-target")
    world, variables = world_and_variables(config, directive, where)
    if url is None:
        return LockstepTarget(world, variables)
    key_file = config.getoption("--aspod-key-file")
    psk = auth.load_key(key_file, "--aspod-key-file") if key_file else simulator_key(url, "--aspod-key-file")
    control = config.getoption("--aspod-control")
    return LiveTarget(url, psk, control_path=None if control is None else Path(control), variables=variables)


def _record(item: pytest.Item) -> dict:
    if RECORD_KEY not in item.stash:
        item.stash[RECORD_KEY] = {"nodeid": item.nodeid, "measurements": {}}
    return item.stash[RECORD_KEY]


@pytest.fixture
def aspod_target(request: pytest.FixtureRequest):
    """A connected bench target: the lock-step world, or the live controller of --aspod-target."""
    target = make_target(request.config)
    record = _record(request.node)
    record["target"] = target.kind
    try:
        yield target
    finally:
        record.update(target.close_record())
        record["measurements"] = target.measurements
        for name, m in target.measurements.items():
            request.node.user_properties.append((name, f"{m['value']}{' ' + m['unit'] if m['unit'] else ''}"))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item: pytest.Item):
    """A bench that asks a target for a plant it does not have is skipped, saying so."""
    outcome = yield
    excinfo = outcome.excinfo
    if excinfo is not None and isinstance(excinfo[1], CannotFault):
        outcome.force_exception(pytest.skip.Exception(f"needs the plant: {excinfo[1]}", _use_item_location=True))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call):
    outcome = yield
    report = outcome.get_result()
    folder = item.config.getoption("--aspod-json")
    if folder is None or RECORD_KEY not in item.stash and not isinstance(item, ScriptItem):
        return
    record = _record(item)
    if report.when == "call" or (report.when == "setup" and report.outcome != "passed"):
        record["outcome"] = report.outcome
        record["duration_s"] = report.duration
        if report.failed:
            crash = getattr(report.longrepr, "reprcrash", None)
            record["error"] = crash.message.splitlines()[0] if crash is not None else str(report.longrepr)[:500]
    if report.when == "teardown":
        path = Path(folder)
        path.mkdir(parents=True, exist_ok=True)
        name = re.sub(r"[^A-Za-z0-9_.-]+", "_", item.nodeid).strip("_") + ".json"
        (path / name).write_text(json.dumps(record, indent=1, default=str))


# ---- teleop scripts as tests -------------------------------------------------------------------------------------

def pytest_collect_file(file_path: Path, parent: pytest.Collector):
    if file_path.suffix == SCRIPT_SUFFIX:
        return ScriptFile.from_parent(parent, path=file_path)
    return None


class ScriptFile(pytest.File):
    def collect(self):
        yield ScriptItem.from_parent(self, name=self.path.name)


class ScriptFailed(Exception):
    def __init__(self, record: dict) -> None:
        super().__init__("a script step failed")
        self.record = record


class ScriptItem(pytest.Item):
    """One `*.aspod` script, run on the target as `aspod teleop --script` (or `aspod bench`) would run it."""

    def runtest(self) -> None:
        from host_tools.teleop.words import TeleopError, script_directive, substitute
        text = self.path.read_text(encoding="utf-8")
        try:
            directive = script_directive(text.splitlines())
        except TeleopError as exc:
            raise pytest.UsageError(f"{self.path}: {exc}") from None
        world = world_asked(directive)
        if world and self.config.getoption("--aspod-target") is not None:
            pytest.skip(f"its first line asks for a world ({' '.join(world)}) that a live target is not given "
                        "from here: start the simulator so and run the script with `aspod teleop --script`")
        target = make_target(self.config, directive, str(self.path))
        record = _record(self)
        try:
            lines = substitute(text.splitlines(), target.variables, all_used=False)
            result = target.run_script("\n".join(lines))
        except TeleopError as exc:
            raise pytest.UsageError(f"{self.path}: {exc}") from None
        finally:
            record.update(target.close_record())
        record.update(target=target.kind, steps=result["steps"], motions=result["motions"],
                      commands=result["commands"], status=result["status"])
        for step in result["steps"]:
            self.user_properties.append((f"line {step['line']}", f"{'ok' if step['ok'] else 'FAILED'}: "
                                                                 f"{step['text']}"))
        if result["status"] != 0:
            raise ScriptFailed(result)

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, ScriptFailed):
            lines = []
            for step in excinfo.value.record["steps"]:
                if not step["ok"]:
                    lines.append(f"line {step['line']}: {step['text']}")
                    lines += [f"    {out}" for out in step["output"]]
            return "\n".join(lines) or "the script failed (a motion did not end as asked)"
        return super().repr_failure(excinfo, style)

    def reportinfo(self):
        return self.path, 0, f"aspod script {self.path.name}"
