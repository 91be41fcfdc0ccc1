"""Joint position and velocity from encoder counts: a constant-velocity Kalman filter.

Model (per axis, joint side, state x = [pos_rad, vel_rad_s]):

    x[k+1] = F x[k] + w,   F = [[1, dt], [0, 1]]
    z[k]   = pos_rad + v,  v ~ quantization of one count

Process noise: continuous white-noise acceleration with spectral density
``accel_psd_rad2_s3`` [rad^2/s^3], discretized as Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]
(filterpy's ``Q_continuous_white_noise``, written out here). The default follows Bar-Shalom, Li and
Kirubarajan, *Estimation with Applications to Tracking and Navigation* (2001), sec. 6.2.2:
the velocity changes over one sample by about sqrt(q dt), so to follow an acceleration of up to
``max_acc_rad_s2`` take q = max_acc^2 * dt. Measurement noise: a count of q_rad radians
quantizes position uniformly, variance q_rad^2 / 12.

Why constant velocity and not constant acceleration: acceleration estimated from quantized
counts at 1 kHz is mostly noise, and the controller takes its acceleration feed-forward from
the motion profile; a third state would cost time and buy nothing the loops use.

Two filters with one interface:

* `SteadyStateEstimator` (the default): the same model with its gains frozen at their
  steady-state values (solved once, at construction, by iterating the reference filter's
  predict/update to convergence: filterpy's operations, in the same order, in numpy, equal to
  the bit (tested), so that starting a controller does not import filterpy and with it
  scipy.stats, 1.2-1.9 s of CPU). With constant dt, Q and R the time-varying gain converges in
  a few hundred ticks, after which both filters compute the same thing; the test checks they
  agree. It costs about 0.3-0.5 us per tick in plain Python against 13-20 us for filterpy's
  numpy predict+update, which alone would exceed the per-axis budget (7 axes at 1 kHz at 20x
  real time leaves about 7 us per axis-tick for everything). Price: during the first ~0.1-0.3 s after a reset it trusts its initial state as if it
  had converged, and it cannot widen its covariance after missed samples (it predicts through them).
* `KalmanEstimator`: filterpy's ``KalmanFilter``, time-varying gains; the reference, and the
  choice if the model ever gets a varying dt or input.

Both share the count handling in `_CountTracker`: 32-bit wrap-around, staleness (no new count
for `stale_ticks` ticks), and glitches (a jump no real motion could make within the elapsed
ticks). The arithmetic of the count checks and of the steady-state filter's step is the joints'
tick's (`firmware_py/joints_tick.py` `count_step`, `filter_step`), written once: these classes
run the same functions on their own fields. A glitch is *flagged and not absorbed*: the sample is dropped, the reference count is
kept, and the caller's fault logic decides. A one-sample spike therefore costs one flag; a
permanent offset keeps flagging on every sample, as it should, until the caller `resync`s.
"""
from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

import numpy as np

from firmware_py.joints_tick import count_step, filter_step

if TYPE_CHECKING:
    from filterpy.kalman import KalmanFilter

COUNT_BITS = 32
COUNT_MODULUS = 1 << COUNT_BITS


class EstimatorFlag(enum.IntFlag):
    """What one update found wrong with its input (the estimate itself stays usable)."""

    NONE = 0
    STALE = 1 << 0     # no new count for `stale_ticks` ticks or more
    GLITCH = 1 << 1    # a count jump larger than physically possible; the sample was dropped


def unwrap_delta(count: int, last_count: int, modulus: int = COUNT_MODULUS) -> int:
    """Signed difference `count - last_count` of two wrapping counters (shortest way round).

    >>> unwrap_delta(3, 0xFFFFFFFE)
    5
    >>> unwrap_delta(0xFFFFFFFE, 3)
    -5
    """
    half = modulus >> 1
    return (count - last_count + half) % modulus - half


@dataclass(frozen=True)
class EstimatorConfig:
    """Settings of one axis's estimator, checked when built."""

    rad_per_count: float            # joint radians per encoder count
    dt_s: float = 0.001             # tick period
    max_vel_rad_s: float = 1.0      # fastest the joint can physically turn (glitch threshold)
    max_acc_rad_s2: float = 2.0     # largest acceleration to follow (sets the process noise)
    accel_psd_rad2_s3: Optional[float] = None  # override q; default max_acc^2 * dt (see module doc)
    stale_ticks: int = 5            # this many ticks without a new count -> STALE
    glitch_margin_counts: int = 4   # slack on top of max_vel * elapsed time

    def __post_init__(self) -> None:
        for name in ("rad_per_count", "dt_s", "max_vel_rad_s", "max_acc_rad_s2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, not {value}")
        if self.accel_psd_rad2_s3 is not None and not self.accel_psd_rad2_s3 > 0:
            raise ValueError("accel_psd_rad2_s3 must be > 0")
        if self.stale_ticks < 1 or self.glitch_margin_counts < 0:
            raise ValueError("stale_ticks must be >= 1 and glitch_margin_counts >= 0")

    @property
    def q_rad2_s3(self) -> float:
        """Acceleration spectral density in use."""
        if self.accel_psd_rad2_s3 is not None:
            return self.accel_psd_rad2_s3
        return self.max_acc_rad_s2 ** 2 * self.dt_s

    @property
    def r_rad2(self) -> float:
        """Measurement variance: uniform quantization of one count."""
        return self.rad_per_count ** 2 / 12.0

    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """F, H, Q, R of the constant-velocity model."""
        dt = self.dt_s
        f = np.array([[1.0, dt], [0.0, 1.0]])
        h = np.array([[1.0, 0.0]])
        q = np.array([[(dt ** 3) / 3., (dt ** 2) / 2.], [(dt ** 2) / 2., dt]]) * self.q_rad2_s3
        r = np.array([[self.r_rad2]])
        return f, h, q, r


def make_kalman_filter(config: EstimatorConfig, pos_rad: float = 0.0) -> KalmanFilter:
    """filterpy's filter for the model, starting at rest at `pos_rad` with a wide velocity prior (the `reference`
    extra: MissingExtra without it)."""
    from kernels.extras import require
    require("reference", "filterpy", what="filterpy's Kalman filter (the estimator's reference)")
    from filterpy.kalman import KalmanFilter      # the reference only: not imported to run a controller
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.F, kf.H, kf.Q, kf.R = config.matrices()
    kf.x = np.array([[pos_rad], [0.0]])
    kf.P = initial_covariance(config)
    return kf


def initial_covariance(config: EstimatorConfig) -> np.ndarray:
    """At rest where the first count says, the velocity anywhere within what the joint can do."""
    return np.diag([config.r_rad2, config.max_vel_rad_s ** 2])


def steady_state_gain(config: EstimatorConfig) -> tuple[float, float, np.ndarray]:
    """Kalman gain (k_pos, k_vel) and posterior covariance P at steady state.

    Iterates the reference filter's predict/update on the model until the gain stops changing:
    filterpy's `KalmanFilter.predict` and `update` (Joseph form) with the same numpy operations in the
    same order, so the fast filter is by construction the limit of the reference one, to the bit
    (tests/test_axis_pipeline.py), without importing filterpy. The iteration takes some thousand
    steps (about 60 ms), so each process does it once per distinct configuration.
    """
    k_pos, k_vel, p = _steady_state_gain(config)
    return k_pos, k_vel, p.copy()


@functools.lru_cache(maxsize=64)
def _steady_state_gain(config: EstimatorConfig, max_iter: int = 200_000, rtol: float = 1e-13) -> tuple[
        float, float, np.ndarray]:
    f, h, q, r = config.matrices()
    p = initial_covariance(config)
    identity = np.eye(2)
    last = None
    for _ in range(max_iter):
        p = 1.0 * np.dot(np.dot(f, p), f.T) + q                  # predict: P = FPF' + Q
        pht = np.dot(p, h.T)                                     # update: S = HPH' + R, K = PH'S^-1
        k = np.dot(pht, np.linalg.inv(np.dot(h, pht) + r))
        i_kh = identity - np.dot(k, h)
        p = np.dot(np.dot(i_kh, p), i_kh.T) + np.dot(np.dot(k, r), k.T)
        gain = k[:, 0].copy()
        if last is not None and np.all(np.abs(gain - last) <= rtol * np.abs(gain)):
            return float(gain[0]), float(gain[1]), p.copy()
        last = gain
    raise RuntimeError("Kalman gain did not converge; check rad_per_count, dt_s and the process noise")


class _CountTracker:
    """Wrap-around, staleness and glitch checks on the raw count; the filters build on it."""

    def __init__(self, config: EstimatorConfig) -> None:
        self.config = config
        self._rad_per_count = config.rad_per_count
        self._max_counts_per_tick = config.max_vel_rad_s * config.dt_s / config.rad_per_count
        self._margin = config.glitch_margin_counts
        self._stale_ticks = config.stale_ticks
        self.last_count: Optional[int] = None  # raw count of the last accepted sample
        self.turns_counts = 0      # unwrapped count of the last accepted sample
        self.offset_rad = 0.0      # added to the measured position (homing sets it)
        self.missed_ticks = 0      # consecutive ticks without a new accepted count
        self.glitches = 0          # total samples dropped as glitches
        self.flags = 0             # EstimatorFlag bits of the last update, as a plain int (fast)

    def _measure(self, count: Optional[int]) -> Optional[float]:
        """Measured position for a new count, or None (no sample, or a dropped glitch): the joints' tick's count
        checks (`joints_tick.count_step`, the one implementation)."""
        last = self.last_count
        z, has_count, last, self.turns_counts, self.missed_ticks, self.flags = count_step(
            count is not None, 0 if count is None else count, last is not None, 0 if last is None else last,
            self.turns_counts, self.missed_ticks, self.offset_rad, self._rad_per_count, self._max_counts_per_tick,
            self._stale_ticks, self._margin)
        self.last_count = last if has_count else None
        if self.flags & EstimatorFlag.GLITCH:
            self.glitches += 1
        return z if z == z else None

    def set_stale_ticks(self, ticks: int) -> None:
        """A new staleness limit (the encoder_stale_s parameter changed), from the next update."""
        if ticks < 1:
            raise ValueError("stale_ticks must be >= 1")
        self._stale_ticks = ticks

    def skip(self, ticks: int) -> None:
        """`ticks` ticks went by without an update (a controller on the wall clock ran late): the next
        count may have moved as far as those ticks allow (the glitch check widens with them)."""
        self.missed_ticks += ticks

    def resync(self, pos_rad: float) -> None:
        """Forget the reference count: the next count is taken as `pos_rad` whatever its value.

        For a deliberate restart after a glitch (the caller resets the fault and re-homes);
        never done on the estimator's own initiative.
        """
        self.last_count = None
        self.offset_rad = pos_rad
        self.missed_ticks = 0


class SteadyStateEstimator(_CountTracker):
    """The constant-velocity Kalman filter with steady-state gains, in plain Python floats.

    `update(count)` once per tick, with the new raw count or None if none arrived; it returns
    the EstimatorFlag bits as an int (0 when all is well). Read `pos_rad` and `vel_rad_s`.
    """

    def __init__(self, config: EstimatorConfig, pos_rad: float = 0.0) -> None:
        super().__init__(config)
        self.k_pos, self.k_vel, self.p_steady = steady_state_gain(config)
        self._dt = config.dt_s
        self.pos_rad = pos_rad
        self.vel_rad_s = 0.0
        self.offset_rad = pos_rad

    def update(self, count: Optional[int]) -> int:
        z = self._measure(count)
        self.pos_rad, self.vel_rad_s = filter_step(self.pos_rad, self.vel_rad_s, math.nan if z is None else z,
                                                   self._dt, self.k_pos, self.k_vel)
        return self.flags

    def skip(self, ticks: int) -> None:
        super().skip(ticks)
        self.pos_rad += self.vel_rad_s * self._dt * ticks     # predicted through them

    def set_position(self, pos_rad: float) -> None:
        """Redefine the present position as `pos_rad` (homing); velocity is kept."""
        shift = pos_rad - self.pos_rad
        self.offset_rad += shift
        self.pos_rad = pos_rad


class KalmanEstimator(_CountTracker):
    """filterpy's time-varying Kalman filter on the same model (the reference)."""

    def __init__(self, config: EstimatorConfig, pos_rad: float = 0.0) -> None:
        super().__init__(config)
        self.kf = make_kalman_filter(config, pos_rad)
        self.offset_rad = pos_rad
        self._z = np.zeros((1, 1))

    @property
    def pos_rad(self) -> float:
        return float(self.kf.x[0, 0])

    @property
    def vel_rad_s(self) -> float:
        return float(self.kf.x[1, 0])

    def skip(self, ticks: int) -> None:
        super().skip(ticks)
        for _ in range(ticks):
            self.kf.predict()

    def update(self, count: Optional[int]) -> int:
        self.kf.predict()
        z = self._measure(count)
        if z is not None:
            self._z[0, 0] = z
            self.kf.update(self._z)
        return self.flags

    def set_position(self, pos_rad: float) -> None:
        shift = pos_rad - self.pos_rad
        self.offset_rad += shift
        self.kf.x[0, 0] = pos_rad
