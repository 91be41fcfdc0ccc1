"""Line coverage reached by a corpus: every input of a target's corpus run again under coverage.py, in a child
process (so that lines run when the modules are imported count too), against the files the target names as
its own (`Target.covers`) and the controller's command handlers (the functions declared with `@handles`, in the
files of the subsystems that own them: firmware_py/handlers.py).

    python -m host_tools.fuzz.coverage_report TARGET CORPUS_DIR OUT.json     (the child; `line_coverage` runs it)
"""
from __future__ import annotations

import ast
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# the files of the command handlers: the controller's own and each subsystem's (tests/test_handlers.py checks these
# are the files of a controller's table)
HANDLER_FILES = ("firmware_py/controller.py", "firmware_py/arm_commands.py", "firmware_py/param_commands.py",
                 "firmware_py/tracker/commands.py")


def _handler_lines(path: Path) -> set[int]:
    """The lines of the functions in `path` decorated with @handles(...)."""
    lines: set[int] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef) and any(
                isinstance(d, ast.Call) and getattr(d.func, "id", "") == "handles" for d in node.decorator_list):
            lines |= set(range(node.body[0].lineno, node.end_lineno + 1))
    return lines


def line_coverage(target: str, corpus: Path, files: tuple[str, ...]) -> dict[str, dict]:
    """{file: {"covered": n, "statements": m, "percent": p}} for each of `files`, and "handlers" (the controller's
    command handlers, in every file of HANDLER_FILES) when the target reaches them."""
    with tempfile.TemporaryDirectory(prefix="aspod-cov-") as tmp:
        data = Path(tmp) / "coverage.json"
        include = ",".join(str(ROOT / f) for f in dict.fromkeys(files + HANDLER_FILES))
        subprocess.run([sys.executable, "-m", "coverage", "run", f"--data-file={tmp}/.coverage",
                        f"--include={include}", "-m", "host_tools.fuzz.coverage_report", target, str(corpus.resolve())],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
        subprocess.run([sys.executable, "-m", "coverage", "json", f"--data-file={tmp}/.coverage", "-o", str(data)],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
        report = json.loads(data.read_text())["files"]
    out: dict[str, dict] = {}
    handlers: set = set()          # (file, line) of every handler's statements
    reached: set = set()
    for name, entry in report.items():
        rel = str(Path(name).resolve().relative_to(ROOT)) if Path(name).is_absolute() else name
        executed, missing = set(entry["executed_lines"]), set(entry["missing_lines"])
        if rel in files:
            out[rel] = _figures(executed, executed | missing)
        if rel in HANDLER_FILES:
            lines = _handler_lines(ROOT / rel) & (executed | missing)
            handlers |= {(rel, n) for n in lines}
            reached |= {(rel, n) for n in lines & executed}
    if reached:
        out["handlers"] = _figures(reached, handlers)
    return out


def _figures(executed: set[int], statements: set[int]) -> dict:
    n = len(statements)
    return {"covered": len(executed), "statements": n, "percent": round(100.0 * len(executed) / n, 1) if n else 0.0}


def _replay_corpus(target_spec: str, corpus: Path) -> None:
    from host_tools.fuzz.targets import load_target
    target = load_target(target_spec)
    stateful = getattr(target, "stateful", False)
    for index, path in enumerate(sorted(p for p in corpus.iterdir() if p.is_file())):
        if stateful and index % target.fresh_every == 0:
            target.fresh()
        try:
            target.one_input(path.read_bytes())
        except Exception:          # noqa: BLE001 (a finding: the campaign reports it; coverage goes on)
            if stateful:
                target.fresh()
    target.close()


if __name__ == "__main__":
    _replay_corpus(sys.argv[1], Path(sys.argv[2]))
