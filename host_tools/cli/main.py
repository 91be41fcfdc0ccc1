"""`aspod`: one command line; each command's options, examples and run in its own module.

    aspod COMMAND [options]     (aspod --help lists the commands; aspod COMMAND --help its options)
    aspod --version;  -v / -q / --log-file PATH / --force before or after the command

`COMMANDS` names each command, its help line and its module, host_tools/cli/<command>.py, which owns
its options (`add_options`, on the shared helpers of host_tools/cli/options.py), its examples
(`EXAMPLES`) and its run (`run(args)`: the Namespace turned, once, into frozen settings,
host_tools/cli/settings.py; nothing below cli/ sees argparse). Only the command being run is
imported and gets its options (`build_parser(only=...)`): `aspod --version` and `--help` import
neither numpy nor the plant (docs/Code_Overview.md, "Starting light"). An option the command does
not have is refused with the command's usage. Diagnostics go through the `aspod` logger (stderr,
bare messages at INFO); results and ready lines go to stdout.

Exit status: 0 ok, 1 a command failed, 2 bad usage or input, 3 link refused, unreachable or lost.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path
from typing import Collection, Optional, Sequence

from protocol.errors import KeyFileError, LinkError

from host_tools.exit_codes import EXIT_FAILED, EXIT_LINK, EXIT_OK, EXIT_USAGE


EXIT_CODES_TEXT = (f"exit status: {EXIT_OK} ok, {EXIT_FAILED} a command failed, {EXIT_USAGE} bad usage or input, "
                   f"{EXIT_LINK} link refused, unreachable or lost, 130 interrupted")
# The examples `aspod --help` shows; each command's own are in its module (`EXAMPLES`).
EXAMPLES = ["aspod sim --pty", "aspod teleop /dev/pts/5 --script benches/tracker_procedure.aspod", "aspod demo",
            "aspod completion bash > ~/.local/share/bash-completion/completions/aspod"]


def _epilog(examples: Sequence[str]) -> str:
    lines = "\n".join(f"  {example}" for example in examples)
    return f"examples:\n{lines}\n\n{EXIT_CODES_TEXT}"


def installed_version(distribution: str = "aspod") -> str:
    """The version in the installed distribution's metadata: the `Version:` line of the first
    `NAME-*.dist-info/METADATA` on sys.path, where importlib.metadata finds it too (tests/test_cli_start.py
    compares them), read without importlib.metadata's imports (email, zipfile, csv), which cost as much as
    Python's own start."""
    prefix = distribution + "-"
    for entry in sys.path:
        try:
            names = sorted(os.listdir(entry or "."))
        except OSError:                 # a zip, a folder gone: importlib.metadata skips it too
            continue
        for name in names:
            if name.startswith(prefix) and name.endswith(".dist-info"):
                try:
                    with open(os.path.join(entry or ".", name, "METADATA"), encoding="utf-8") as metadata:
                        for line in metadata:
                            if line.startswith("Version:"):
                                return line.split(":", 1)[1].strip()
                            if not line.strip():        # the headers end at the first blank line
                                break
                except OSError:
                    continue
    return "unknown (not installed)"    # run from a source tree that was never installed


class _VersionAction(argparse.Action):
    """--version: the installed package's version, from its metadata, read only when asked."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kwargs) -> None:
        super().__init__(option_strings, dest=dest, default=argparse.SUPPRESS, nargs=0,
                         help="show the program's version and exit")

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(f"{parser.prog} {installed_version()}")
        parser.exit()


def add_logging_args(parser: argparse.ArgumentParser) -> None:
    """-v, -q, --log-file and --force: before the command or after it (`aspod -v sim`, `aspod sim -v`)."""
    group = parser.add_argument_group("logging")
    group.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                       help="more diagnostics on stderr (repeatable: -vv for debug)")
    group.add_argument("-q", "--quiet", action="count", default=argparse.SUPPRESS,
                       help="fewer diagnostics on stderr: -q warnings and errors only, -qq errors only")
    group.add_argument("--log-file", type=Path, default=argparse.SUPPRESS, metavar="PATH",
                       help="also write the diagnostics, time-stamped, to PATH (appended)")
    outputs = parser.add_argument_group("output files")
    outputs.add_argument("--force", action="store_true", default=argparse.SUPPRESS,
                         help="write an output over an existing file that is not of its kind (a capture over a text "
                              "file, say); an output never replaces an input of the same run (docs/sessions.md)")


def setup_logging(verbose: int = 0, quiet: int = 0, log_file: Optional[Path] = None) -> None:
    """The `aspod` logger: diagnostics on stderr as bare messages (INFO by default, so the lines that scripts
    and tests read stay as they were; -q raises it, -v lowers it), and to `log_file` with time and level at INFO
    (DEBUG with -v): -q quiets the terminal, never the record."""
    import logging                      # here, not at the top: `aspod --version` and `--help` need none of it
    shown = min(max(logging.INFO - 10 * verbose + 10 * quiet, logging.DEBUG), logging.CRITICAL)
    kept = max(logging.INFO - 10 * verbose, logging.DEBUG)
    log = logging.getLogger("aspod")
    for handler in list(log.handlers):
        log.removeHandler(handler)
        handler.close()
    log.propagate = False
    stderr = logging.StreamHandler(sys.stderr)
    stderr.setFormatter(logging.Formatter("%(message)s"))
    stderr.setLevel(shown)
    log.addHandler(stderr)
    log.setLevel(shown)
    if log_file is not None:
        to_file = logging.FileHandler(log_file, encoding="utf-8")
        to_file.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        to_file.setLevel(kept)
        log.addHandler(to_file)
        log.setLevel(min(shown, kept))


# The commands in the order `aspod --help` lists them: name, the keywords of its parser (help, description), and
# its module under host_tools/cli, which owns the command's options (`add_options`), its examples (`EXAMPLES`) and
# its run (`run(args)`); imported only for the command being run (`build_parser`).
COMMANDS = (
    ("sim", dict(help="run the controller and its plant; prints ASPOD-LINK, ASPOD-KEY and ASPOD-CONTROL "
                      "lines"), "sim"),
    ("plant", dict(help="run only the plant, in real time, on a python-can interface; "
                        "prints an ASPOD-PLANT ready line"), "plant"),
    ("firmware", dict(help="run only the controller, its HAL on a python-can interface; "
                           "prints ASPOD-LINK and ASPOD-KEY lines"), "firmware"),
    ("ports", dict(help="list the serial ports and your running simulators (their links)"), "ports"),
    ("teleop", dict(help="console to a controller: interactive, or a script"), "teleop"),
    ("bench", dict(help="run a teleop script against the whole world on the simulated clock "
                        "(deterministic, fast); the plant's true state at the end"), "bench"),
    ("campaign", dict(help="run a bench over a matrix of settings, one row per run, on Dask "
                           "(a local cluster on every core, or --scheduler)"), "campaign"),
    ("fuzz", dict(help="fuzz the protocol: in process, coverage-guided (atheris), on a target of the "
                       "emulator's; or black-box against a live link; or replay a finding"), "fuzz"),
    ("plan", dict(help="the report's trajectory planning for two arms carrying one object: time-optimal "
                       "on the phase plane, minimum cost by dynamic programming (docs/planning.md)"), "plan"),
    ("demo", dict(help="the arm picks up debris and drops it in the bin, on the simulated clock; "
                       "reports the positioning error of each step"), "demo"),
    ("tracker-day", dict(help="the solar tracker through a simulated day at Tucson, on the "
                              "simulated clock; pointing error, lag and relay switchings"), "tracker_day"),
    ("log", dict(help="decode a session capture (pcapng): every frame, counts, a table or a plot"), "log"),
    ("proxy", dict(help="a man in the middle between host and controller: impairs, shows and records "
                        "the link; prints ASPOD-LINK for the host"), "proxy"),
    ("replay", dict(help="re-simulate a recorded session (aspod sim/demo --record) and report "
                         "the first divergence"), "replay"),
    ("wireshark", dict(help="write the Wireshark Lua dissector for this protocol's captures"), "wireshark"),
    ("schema", dict(help="the protocol's declaration as data (--json): framing, messages, fields, enumerations, "
                         "constants, for a generator of the link's other end"), "schema"),
    ("conform", dict(help="the conformance suite against any controller speaking the link protocol: a simulator, "
                          "or a firmware on a serial device; a report and JUnit XML"), "conform"),
    ("key", dict(help="make a link key (new FILE, mode 0600) or name one to compare two ends' (fingerprint FILE)"),
     "key"),
    ("completion", dict(help="print a shell completion script (bash or zsh)",
                        description="print a completion script for aspod: bash (source it, or put it in "
                                    "~/.local/share/bash-completion/completions/aspod) or zsh (put it as "
                                    "_aspod in a folder on $fpath)"), "completion"),
)


def build_parser(only: Optional[Collection[str]] = None) -> argparse.ArgumentParser:
    """The `aspod` parser, with the options of the commands `only` names (None: every command's).

    The others are there by name and help, which is all `aspod --help`, `aspod --version` and argparse's
    choice of a command need: so a command imports only what its own options need, and `aspod --version`
    loads neither numpy nor the plant (bench/bench_start.py).
    """
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(prog="aspod", description="ASPOD controller emulator",
                                     epilog=_epilog(EXAMPLES), formatter_class=formatter)
    parser.add_argument("--version", action=_VersionAction)
    add_logging_args(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, keywords, module in COMMANDS:
        if only is None or name in only:
            command = command_module(module)
            command_parser = sub.add_parser(name, epilog=_epilog(command.EXAMPLES), formatter_class=formatter,
                                            **keywords)
            add_logging_args(command_parser)
            command.add_options(command_parser)
        else:
            sub.add_parser(name, formatter_class=formatter, **keywords)
    return parser


def command_parser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    """The parser of the command `name` within `build_parser`'s `parser`."""
    return next(action.choices[name] for action in parser._actions if action.dest == "command")


def command_module(module: str):
    """host_tools/cli/<module>.py: a command's options, examples and run."""
    import importlib
    return importlib.import_module(f"host_tools.cli.{module}")


def host_key(path: Optional[Path], url: str) -> bytes:
    """The key a host tool uses for the link `url`: --key-file, else the key of this user's simulator serving
    `url` (host_tools/client/control.py `simulator_key`)."""
    if path is not None:
        from protocol import auth
        return auth.load_key(path, "--key-file")
    from host_tools.client.control import simulator_key
    return simulator_key(url)


def run_command(args: argparse.Namespace) -> int:
    """The command's own `run`: it turns the Namespace into its settings (host_tools/cli/settings.py) and runs."""
    for name, _, module in COMMANDS:
        if name == args.command:
            return command_module(module).run(args)
    return EXIT_USAGE


def with_script_directive(args: argparse.Namespace, argv: Sequence[str]) -> argparse.Namespace:
    """`aspod bench SCRIPT`: the options of the script's first line (`#! aspod bench --sun-start ...`) come first,
    the command line's after them (so they win), as the pytest plugin and `aspod campaign` read a script. A
    script that cannot be read is left for the command to refuse; a first line that gives more than the world
    (words.py `script_directive`) is refused here: TeleopError (a ValueError)."""
    from host_tools.teleop.words import TeleopError, read_script, script_directive
    try:
        first = read_script(args.script, option="script")[:1]
    except (OSError, TeleopError):
        return args
    directive = script_directive(first)
    if not directive:
        return args
    at = list(argv).index("bench") + 1
    return build_parser(["bench"]).parse_args([*argv[:at], *directive, *argv[at:]])


def _terminated(signum, frame) -> None:
    raise SystemExit(128 + signum)


def command_word(argv: Sequence[str]) -> Optional[str]:
    """The command `argv` names: its first word that is not an option nor --log-file's path; None if there is none,
    or that word is no command (argparse then says so)."""
    value_next = False
    for word in argv:
        if value_next:
            value_next = False
        elif word.startswith("--") and "=" not in word and len(word) > 3 and "--log-file".startswith(word):
            value_next = True               # --log-file PATH (argparse takes any unambiguous prefix: --log PATH)
        elif not word.startswith("-"):
            return word if any(word == name for name, _, _ in COMMANDS) else None
    return None


def main(argv: Optional[Sequence[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    word = command_word(argv)
    parser = build_parser(only=() if word is None else (word,))
    args, unknown = parser.parse_known_args(argv)
    if unknown:                 # said with the command's usage (argparse would give the top-level one)
        command_parser(parser, args.command).error(f"unrecognized arguments: {' '.join(unknown)}")
    if args.command == "bench":
        try:
            args = with_script_directive(args, argv)
        except ValueError as exc:               # logging is not set up yet: the script's line is refused plainly
            print(f"aspod bench: {args.script}: {exc}", file=sys.stderr)
            return EXIT_USAGE
    args.argv = tuple(argv)            # the command line as given (a campaign keeps it in its record)
    from host_tools.cli.settings import claims
    try:
        claims(args)                            # --log-file: not an input, a folder, a file of another kind, ...
        setup_logging(getattr(args, "verbose", 0), getattr(args, "quiet", 0), getattr(args, "log_file", None))
    except ValueError as exc:
        print(f"aspod: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:                      # (claimed, then taken away)
        print(f"aspod: --log-file: cannot write {exc.filename}: {exc.strerror}", file=sys.stderr)
        return EXIT_USAGE
    # SIGTERM ends a command as an error would, through every `finally`: a live capture is put in place whole, an
    # output half written is removed (host_tools/outputs.py). Commands that run until stopped set their own.
    before = signal.signal(signal.SIGTERM, _terminated)
    try:
        return _run(args)
    finally:
        signal.signal(signal.SIGTERM, before)


def _run(args: argparse.Namespace) -> int:
    import logging
    log = logging.getLogger("aspod")
    try:
        return run_command(args)
    except BrokenPipeError:                     # `aspod log ... | head`: the reader has all it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # no second complaint at exit
        return 128 + signal.SIGPIPE
    except (KeyFileError, ValueError) as exc:   # bad key file, or settings out of their bounds
        log.error(f"aspod: {exc}")
        return EXIT_USAGE
    except OSError as exc:                      # a port that cannot be opened or bound
        log.error(f"aspod: {exc}")
        return EXIT_LINK
    except LinkError as exc:
        log.error(f"aspod: link: {exc}")
        return EXIT_LINK
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
