"""The house rules of docs/Code_Overview.md, checked: import borders, one clock, no unused names."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ["kernels", "timebase", "protocol", "firmware_py", "hil_sim", "host_tools"]
MAY_IMPORT = {
    "kernels": set(),
    "timebase": set(),
    "protocol": {"timebase"},
    "firmware_py": {"kernels", "protocol", "timebase"},
    "hil_sim": {"kernels", "protocol", "timebase"},
    "host_tools": {"kernels", "protocol", "timebase", "firmware_py", "hil_sim"},
}


def our_imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
            [node.module] if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 else [])
        found |= {n.split(".")[0] for n in names if n.split(".")[0] in PACKAGES}
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_packages_import_only_across_allowed_borders(package):
    for path in (ROOT / package).rglob("*.py"):
        wrong = our_imports(path) - MAY_IMPORT[package] - {package}
        assert not wrong, f"{path.relative_to(ROOT)} imports {wrong}"


# host_tools inside: each part may import only the parts before it (docs/Code_Overview.md)
HOST_LAYERS = ["exit_codes", "datetimes", "strict_json", "outputs", "progress", "plan", "sessions", "worlds", "client", "teleop", "apps", "campaign", "fuzz", "conform", "cli",
               "plugin"]


def host_part(path: Path) -> str:
    parts = path.relative_to(ROOT / "host_tools").parts
    return parts[0] if len(parts) > 1 else path.stem


def test_host_tools_parts_import_only_the_parts_below_them():
    for path in (ROOT / "host_tools").rglob("*.py"):
        if path.name == "__init__.py" and path.parent == ROOT / "host_tools":
            continue
        me = host_part(path)
        assert me in HOST_LAYERS, f"{path.relative_to(ROOT)}: a part of host_tools not in the layering"
        below = set(HOST_LAYERS[:HOST_LAYERS.index(me)])
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("host_tools"):
                names = node.module.split(".")[1:2] or [a.name for a in node.names]
                wrong = set(names) - below - {me}
                assert not wrong, f"{path.relative_to(ROOT)} imports host_tools.{wrong}"


def test_only_the_clock_module_reads_os_time_or_sleeps():
    """Everywhere, tests and benchmarks too: time comes from `timebase` (a benchmark's stopwatch is
    `RealClock.precise_now`)."""
    offenders = []
    for package in (*PACKAGES, "tests", "bench"):
        for path in (ROOT / package).rglob("*.py"):
            if path == ROOT / "timebase" / "clock.py":
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "time" \
                        and node.attr in ("time", "sleep", "monotonic", "perf_counter", "time_ns", "monotonic_ns"):
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} time.{node.attr}")
                elif _reads_the_date(node):
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} {ast.unparse(node)}")
    assert offenders == []


def _reads_the_date(node: ast.AST) -> bool:
    """A call that reads today's date or time itself: `time.strftime(fmt)`, `time.localtime()` and the like with
    no timestamp given, `datetime.now()`, `datetime.utcnow()`, `date.today()` (give them
    `RealClock.wall_time()` instead)."""
    if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
            and isinstance(node.func.value, ast.Name)):
        return False
    owner, name, given = node.func.value.id, node.func.attr, len(node.args) + len(node.keywords)
    if owner == "time":
        return (name == "strftime" and given < 2) or (name in ("localtime", "gmtime", "ctime", "asctime")
                                                      and given == 0)
    return owner in ("datetime", "date") and name in ("now", "utcnow", "today")


def test_no_unused_imports_or_undefined_names():
    done = subprocess.run([sys.executable, "-m", "pyflakes", *PACKAGES, "tests", "bench"], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_only_the_cli_reads_argparse():
    """Commands turn their Namespace into settings at the edge (host_tools/cli/settings.py); below cli/, nothing
    imports argparse or names a Namespace."""
    offenders = []
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            if path.is_relative_to(ROOT / "host_tools" / "cli"):
                continue
            text = path.read_text()
            if "argparse" in our_and_std_imports(path) or "Namespace" in text:
                offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


def our_and_std_imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module.split(".")[0])
    return found
