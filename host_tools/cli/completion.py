"""`aspod completion bash|zsh`: a shell completion script, from the whole parser (shtab)."""
from __future__ import annotations


import argparse
from host_tools.exit_codes import EXIT_OK

SHELLS = ("bash", "zsh")


# ---- the command line: its options, examples and run --------------------------------------------------------

EXAMPLES = [
    "aspod completion bash > ~/.local/share/bash-completion/completions/aspod",
    "aspod completion zsh > ~/.zfunc/_aspod",
]


def add_options(completion: argparse.ArgumentParser) -> None:
    completion.add_argument("shell", choices=SHELLS)


def run(args: argparse.Namespace) -> int:
    import shtab

    from host_tools.cli.main import build_parser
    print(shtab.complete(build_parser(), shell=args.shell))
    return EXIT_OK
