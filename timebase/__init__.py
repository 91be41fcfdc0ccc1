"""Time for every other package: the one injected clock (DESIGN decision 1).

`timebase` sits below `protocol`, `firmware_py`, `hil_sim` and `host_tools`, and
imports none of them, so each may use it without breaking the import order.
"""
from timebase.clock import Clock, RealClock, SimClock, TimingReport
from timebase.paced import PacedClock, RateMeter

__all__ = ["Clock", "PacedClock", "RateMeter", "RealClock", "SimClock", "TimingReport"]
