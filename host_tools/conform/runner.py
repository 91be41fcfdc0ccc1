"""Run the checks in order on one probe, one report line each as it ends.

A check that fails leaves the line as it was at the failure: the runner takes the probe out of any hostile mode
(muted, events held) and starts a new session before the next check, so that one broken rule costs one check. A
line that fails (the port gone) ends the run: the checks not run are skipped, saying so. When no session can be
made at all, the checks that need one fail at once, naming the handshake's failure.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import serial

from host_tools.conform.checks import MUST, Check, Context, Fail, Options, Skip
from host_tools.conform.probe import Probe

PASS, FAIL, SKIP = "PASS", "FAIL", "SKIP"


@dataclass
class Result:
    check: Check
    status: str
    detail: str = ""          # PASS: a note; SKIP: why
    expected: str = ""        # FAIL: what the rule expects
    seen: str = ""            # FAIL: what came
    duration_s: float = 0.0

    @property
    def failed_must(self) -> bool:
        return self.status == FAIL and self.check.level == MUST

    def lines(self) -> list[str]:
        head = f"{self.status} {self.check.name} ({self.check.level}, {self.check.cites})"
        if self.status == FAIL:
            return [head, f"     expected: {self.expected}", f"     saw: {self.seen}"]
        return [f"{head}: {self.detail}" if self.detail else head]


def run_checks(probe: Probe, checks: Sequence[Check], options: Options,
               report: Callable[[Result], None] = lambda result: None) -> list[Result]:
    ctx = Context(probe, options)
    results: list[Result] = []
    broken: Optional[str] = None          # why the line is gone
    no_session: Optional[str] = None      # why no session can be made
    for check in checks:
        started = probe.now()
        if broken is not None:
            result = Result(check, SKIP, f"not run: the line failed ({broken})")
        elif check.motion and not options.allow_motion:
            result = Result(check, SKIP, "drives outputs (Enable): only with --allow-motion")
        elif check.slow and options.skip_slow:
            result = Result(check, SKIP, "slow: --skip-slow")
        elif no_session is not None:
            result = Result(check, FAIL, expected="a session", seen=f"none can be made ({no_session})")
        else:
            result, broken = _run_one(ctx, check)
            if result.status == FAIL and broken is None and not probe.up and not probe.link.handshake_seen.verified:
                no_session = f"{check.name}: nothing verifies under this key"   # another handshake would not either
            elif result.status == FAIL and broken is None:
                broken = _recover(ctx)
                if broken is None and not probe.up:
                    no_session = f"a new handshake after {check.name} failed: link {probe.link.state.value}"
        result.duration_s = probe.now() - started
        probe.line_error = broken
        results.append(result)
        report(result)
    return results


def _run_one(ctx: Context, check: Check) -> tuple[Result, Optional[str]]:
    """The check's result, and why the line failed if it did."""
    try:
        note = check.run(ctx)
    except Fail as exc:
        return Result(check, FAIL, expected=exc.expected, seen=exc.seen), None
    except Skip as exc:
        return Result(check, SKIP, str(exc)), None
    except (serial.SerialException, OSError) as exc:
        return Result(check, FAIL, expected="the line open", seen=f"it failed: {exc}"), str(exc)
    return Result(check, PASS, note or ""), None


def _recover(ctx: Context) -> Optional[str]:
    """After a failed check: the probe out of its hostile modes and a new session; why the line failed, if it
    did."""
    probe = ctx.probe
    probe.mute = False
    probe.hold_events = False
    try:
        probe.pump()
        probe.connect()
    except (serial.SerialException, OSError) as exc:
        return str(exc)
    return None
