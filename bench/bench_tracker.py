"""Solar tracker through a clear day: the report's relay logic at several dial settings against the feed-forward.

The goal: show, as figures and as a PNG plot of pointing error over a simulated day, that with
the dial too low the tracker lags the sun and too high it hunts between leading and lagging;
at the best dial, the RMS and maximum pointing error over a clear day and the number of relay
switchings; against that, the feed-forward on the same day, with an RMS pointing error of at
most 0.2 deg and at least 3x lower, and fewer relay switchings.

How. `host_tools.apps.tracker_day.run_day` (what `aspod tracker-day` runs: the tracker's firmware
and plant every 10 ms, from when the sun climbs above 5 deg to when it sinks below it), on
the design day, the June solstice at Tucson (the sun's fastest azimuth: 1.5 deg/min at
transit), clear sky, seed 0. The relay logic at dials `DIALS` (both axes alike), then the
feed-forward with the dial at 100 % (it only caps the speed there). The best relay setting is
the dial with the lowest RMS pointing error. The days run two at a time (the machine has two
cores); each is deterministic, so only the wall times move from run to run. `--quick` runs
11:00-13:00 (through transit) instead of the whole day.

Output: one row per run (RMS, max and p95 pointing error; mean lag along the sun's path,
positive when behind; the share of the time ahead of the sun; relay switchings and
reversals; the share of the time the azimuth motor runs), the verdicts (the low dial lags, the
high one hunts, the feed-forward's goal), and two PNGs in `bench/out/`:
`tracker_dials.png` (the low, high and best dials, the best drawn last, on top) and `tracker_feedforward.png` (the best
dial against the feed-forward).
"""
from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from datetime import time
from pathlib import Path
from typing import Optional

from host_tools.apps.tracker_day import DayResult, DaySettings, plot_days, run_day

DIALS = (3.0, 20.0, 40.0, 60.0, 80.0, 100.0)     # percent; 3 % is below the sun's fastest rate (4.3 % of full speed)
LOW_DIAL, HIGH_DIAL = DIALS[0], DIALS[-1]
QUICK_WINDOW = (time(11, 0), time(13, 0))
GOAL_RMS_DEG = 0.2
GOAL_RATIO = 3.0
OUT = Path(__file__).with_name("out")


@dataclass
class TrackerBench:
    relay: dict = field(default_factory=dict)       # dial -> summary
    feedforward: Optional[dict] = None
    best_dial: Optional[float] = None
    error: Optional[str] = None


def _run(settings: DaySettings) -> DayResult:
    return run_day(settings)


def _name(settings: DaySettings) -> str:
    return "feed-forward (cap 100)" if settings.mode == "feedforward" else f"relay, dial {settings.dial_pct[0]:g} %"


def main(quick: bool = False, workers: int = 2) -> TrackerBench:
    start, end = QUICK_WINDOW if quick else (None, None)
    runs = [DaySettings(mode="relay", dial_pct=(d, d), start=start, end=end) for d in DIALS]
    runs.append(DaySettings(mode="feedforward", dial_pct=(100.0, 100.0), start=start, end=end))
    span = f"{start:%H:%M}-{end:%H:%M}" if quick else "sun above 5 deg"
    print(f"Solar tracker, {runs[0].day} at {runs[0].site.name}, clear sky, {span}, 10 ms steps; "
          f"{len(runs)} days, {workers} at a time")
    bench = TrackerBench()
    results: list = [None] * len(runs)
    try:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(_run, settings): i for i, settings in enumerate(runs)}
            for done, future in enumerate(as_completed(futures), 1):     # a line a day as it ends: a long run shows
                results[futures[future]] = day = future.result()            # where it is
                print(f"  day {done} of {len(runs)} done: {_name(day.settings)}, "
                      f"{day.summary()['wall_time_s']:.0f} s of wall time", flush=True)
    except Exception as exc:             # a run that could not run at all: say which and why
        bench.error = f"{type(exc).__name__}: {exc}"
        print(f"  FAILED: {bench.error}")
        return bench
    relay = results[:-1]
    ff = results[-1]
    summaries = [r.summary() for r in results]
    first = summaries[0]
    print(f"  {first['start_local'][11:16]} to {first['end_local'][11:16]} local standard time, "
          f"{first['sim_time_s'] / 3600:.2f} simulated h a day")
    print()
    print(f"  {'run':<22} {'RMS':>7} {'max':>7} {'p95':>7} {'lag':>8} {'ahead':>6} {'switch':>7} {'revers':>7} "
          f"{'az on':>6} {'wall s':>7} {'x real':>7}")
    for r, s in zip(results, summaries):
        print(f"  {_name(r.settings):<22} {s['rms_pointing_error_deg']:7.3f} {s['max_pointing_error_deg']:7.3f} "
              f"{s['p95_pointing_error_deg']:7.3f} {s['mean_lag_deg']:+8.3f} {100 * s['lead_fraction']:5.1f}% "
              f"{s['relay_switchings']:7d} {s['reversals']:7d} {100 * s['axes']['az']['motor_on_fraction']:5.1f}% "
              f"{s['wall_time_s']:7.1f} {s['speed_x_real_time']:7.0f}")
    print("  (deg; lag = mean error along the sun's path, + behind; ahead = share of the time ahead of the sun; "
          "switch = relay closings and openings, both axes; revers = closings against the previous one; "
          "az on = share of the time the azimuth motor runs)")
    print()
    bench.relay = {r.settings.dial_pct[0]: s for r, s in zip(relay, summaries)}
    bench.feedforward = summaries[-1]
    low, high = bench.relay[LOW_DIAL], bench.relay[HIGH_DIAL]
    best_result = min(relay, key=lambda r: r.summary()["rms_pointing_error_deg"])
    bench.best_dial = best_result.settings.dial_pct[0]
    best = bench.relay[bench.best_dial]
    lags = low["mean_lag_deg"] > 5 * max(best["mean_lag_deg"], 0.01) and low["lead_fraction"] < 0.05
    print(f"  dial {LOW_DIAL:g} % (too low): mean lag {low['mean_lag_deg']:+.3f} deg against {best['mean_lag_deg']:+.3f} "
          f"at the best dial, ahead of the sun {100 * low['lead_fraction']:.1f} % of the time: "
          f"{'lags the sun' if lags else 'does NOT lag clearly'}")
    hunts = high["reversals"] > 10 * max(best["reversals"], 1) and 0.2 < high["lead_fraction"] < 0.8
    print(f"  dial {HIGH_DIAL:g} % (too high): {high['reversals']} reversals and {high['relay_switchings']} switchings "
          f"against {best['reversals']} and {best['relay_switchings']} at the best dial, ahead of the sun "
          f"{100 * high['lead_fraction']:.1f} % of the time: {'hunts' if hunts else 'does NOT hunt'}")
    print(f"  best relay setting: dial {bench.best_dial:g} %: RMS {best['rms_pointing_error_deg']:.3f} deg, "
          f"max {best['max_pointing_error_deg']:.3f} deg, {best['relay_switchings']} relay switchings")
    ffs = bench.feedforward
    ratio = best["rms_pointing_error_deg"] / ffs["rms_pointing_error_deg"] if ffs["rms_pointing_error_deg"] > 0 \
        else float("inf")
    met = (ffs["rms_pointing_error_deg"] <= GOAL_RMS_DEG and ratio >= GOAL_RATIO
           and ffs["relay_switchings"] < best["relay_switchings"])
    print(f"  feed-forward: RMS {ffs['rms_pointing_error_deg']:.4f} deg (goal <= {GOAL_RMS_DEG}), "
          f"{ratio:.1f}x lower than the best relay setting (goal >= {GOAL_RATIO:g}x), max "
          f"{ffs['max_pointing_error_deg']:.3f} deg, {ffs['relay_switchings']} switchings against "
          f"{best['relay_switchings']}: goal {'met' if met else 'NOT met'}")
    os.makedirs(OUT, exist_ok=True)
    by_dial = {r.settings.dial_pct[0]: r for r in relay}
    dials_png, ff_png = OUT / "tracker_dials.png", OUT / "tracker_feedforward.png"
    plot_days([by_dial[LOW_DIAL], by_dial[HIGH_DIAL], best_result], str(dials_png),
              title=f"Relay logic: dial too low ({LOW_DIAL:g} %) lags, too high ({HIGH_DIAL:g} %) hunts; "
                    f"best {bench.best_dial:g} %")
    plot_days([best_result, ff], str(ff_png), title="The best relay setting against the sun-rate feed-forward")
    print(f"  plots: {dials_png}, {ff_png}")
    return bench


if __name__ == "__main__":
    import sys
    main(quick="--quick" in sys.argv)
