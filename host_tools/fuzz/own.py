"""Your own fuzz target's module, from its spec (`module:factory` or `path/to/file.py:factory`).

Apart from the other fuzz modules, and importing only the standard library, since the in-process child names it
to atheris' import hook before anything under test is imported (host_tools/fuzz/child.py).
"""
from __future__ import annotations

import sys
from pathlib import Path


def own_module(spec: str) -> str:
    """The module of your own target `spec`: `module:factory`, or `path/to/file.py:factory`, whose folder is then
    put first on the import path (so a file of examples/ is fuzzed as the docs show it)."""
    module, _, _ = spec.rpartition(":")
    if module.endswith(".py"):
        folder = str(Path(module).resolve().parent)
        if folder not in sys.path:
            sys.path.insert(0, folder)
        return Path(module).stem
    return module
