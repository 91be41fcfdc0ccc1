"""numba's cache, as kernels/__init__.py says it: the first process compiles a kernel, the next ones load it from
`__pycache__/` beside the kernel's source file, and an edit of that file compiles it once more."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("numba")

ROOT = Path(__file__).resolve().parent.parent
KERNEL = '''
def scale(x, k):
    return x * k


def kernel(xs, k):
    total = 0.0
    for x in xs:
        total += scale(x, k)
    return total
'''
# In a child: compile `kernel` (with its helper) through compile_kernel, call it, say what numba's cache did.
CHILD = '''
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import cached_kernel
from kernels import compile_kernel
compiled = compile_kernel(cached_kernel.kernel, "test kernel", helpers=(cached_kernel.scale,))
value = compiled(np.arange(4.0), 2.0)
stats = compiled.stats
print(json.dumps({"value": value, "hits": sum(stats.cache_hits.values()), "misses": sum(stats.cache_misses.values())}))
'''


def run_child(folder: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT")}
    done = subprocess.run([sys.executable, "-c", CHILD, str(folder)], capture_output=True, text=True, cwd=ROOT,
                          env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_the_first_process_compiles_the_next_load_and_an_edit_compiles_again(tmp_path):
    source = tmp_path / "cached_kernel.py"
    source.write_text(KERNEL)
    assert run_child(tmp_path) == {"value": 12.0, "hits": 0, "misses": 1}
    assert sorted(p.suffix for p in (tmp_path / "__pycache__").glob("cached_kernel.kernel-*")) == [".nbc", ".nbi"]
    assert run_child(tmp_path) == {"value": 12.0, "hits": 1, "misses": 0}
    source.write_text(KERNEL.replace("x * k", "x * k + 0.0"))        # a new size: the index no longer matches
    assert run_child(tmp_path) == {"value": 12.0, "hits": 0, "misses": 1}
    assert run_child(tmp_path) == {"value": 12.0, "hits": 1, "misses": 0}
