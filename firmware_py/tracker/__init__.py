"""The solar tracker's controller: the report's control box, its relay logic, its interlocks, a sun-rate feed-forward.

The report ("SOLAR TRACKER" and its OPERATING INSTRUCTIONS, seed/000_54a4d1d9271955c2.txt)
describes two independent directional systems (azimuth, elevation), each a gear train, a
90 VDC motor on an adjustable speed controller, and a pair of photocells at a right angle
whose voltage difference says on which side the sun is; and a control box with a main
power switch, a sensor power switch, a control mode switch (manual / sensor), a direction
switch (CW / CCW), a speed switch (brake / on) and a speed dial. The box lives here, in the
controller; the operator works it over the link (`switch`, `dial`; protocol/messages.py),
a remote control box. The plant (relays, motors, cells) is across the HAL bus: this module
sends TRACKER_CMD and reads TRACKER_SENSE and TRACKER_POS (protocol/hal.dbc) through
`firmware_py/hal.py`, and nothing else.

One box, two axes. The report's figure of the box is not in the text; its block diagram
has two independent directional systems, and the sun's two rates differ sevenfold (at
Tucson in June up to 1.5 deg/min in azimuth, 0.21 deg/min in elevation), so one dial could
not suit both. So the mode, direction and speed switches and the dial are one per axis
(ASSUMED), addressed with an `axis` argument that defaults to both (`switch mode sensor`
sets both; `dial 40 az` one). Main power and sensor power are one each, as TRACKER_CMD
carries one of each. At boot: main off, sensor off, manual, CW, speed at brake, dial 0.

The speed dial is a potentiometer read by a 10-bit ADC in the report's box: a setting is
quantized to counts 0..1023 (`round(pct / 100 x 1023)`), and the dial reads, and the speed
controller gets, counts / 1023 (0.098 % a count). Telemetry reports the quantized value.

Per axis, each 10 ms (`step`, the TRACKER_CMD cycle):

* Drive is permitted only while the supervisor allows outputs (ENABLED), main power is on,
  the axis's speed switch is on and TRACKER_POS is fresh (its angles and limit switches
  known). Otherwise the relays open at once and the brake is applied (the speed switch's
  Brake position: the plant's dynamic brake). Motor power (TRACKER_CMD `motor_power`)
  follows the main switch while outputs are allowed; sensor power follows its switch always
  (the cells drive nothing, and the operator may watch them while idle).
* Manual mode: the direction switch picks the relay (CW or CCW), the dial sets the duty.
* Sensor mode, the report's relay logic: the photocell difference d = a - b (> 0: the sun is
  CW of the focal axis), low-passed (`trk_filter_s`, first order, on each new TRACKER_SENSE),
  closes the CW relay when d > +deadband and the CCW relay when d < -deadband
  (`trk_deadband_mv`); a closed relay opens when |d| falls below deadband - hysteresis
  (`trk_hyst_mv`); the duty is the dial's. Below `trk_sun_min_v` for the pair's sum (the
  cells' total: clouds, night, or the sun far outside their view) the axis holds, relays
  open: no direction to follow, so no hunting on noise. Sensor power off, or TRACKER_SENSE
  stale, in sensor mode: no drive.
* Relays: the two of an axis are never both closed (one relay state per axis, -1/0/+1; the
  HAL sends an impossible both-closed request as both open and counts it; the plant's relays
  are interlocked as well). Anti-chatter dwell: a relay closes only `trk_dwell_s` after the
  axis's previous relay change; opening never waits (a stop is never delayed), so a
  reversal is CW -> open -> (dwell) -> CCW. A relay does not close towards a closed travel
  limit switch, and opens when one closes (the plant's switches cut the drive too).
* Speed switch to brake, main power off, the supervisor's safe state: no drive at once.

Interlocks (the report: "ALWAYS keep the speed dial on low when starting operation. This
includes the transition from manual mode to the sensor mode and when switching direction";
instructions 1, 4, 5, 7 and the IMPORTANT note): starting (speed switch to on, or main power
on while a speed switch is on), changing the control mode, or changing direction is refused
with DIAL_NOT_LOW unless the dial of each axis it concerns is at or below
`trk_dial_low_pct`; a refused command changes nothing and counts in `refusals`. Putting a
switch where it already is changes nothing and is accepted; speed to brake, main or sensor
power off are always accepted. A position the switch does not have is refused with
SWITCH_POSITION, main or sensor power for one axis only with OUT_OF_RANGE.

The safe state (the supervisor's one path; also Disable) runs `safe`: relays open, brakes
on, motor power off, sent at once; and both speed switches go to brake (as a motor
starter's no-volt release), so every restart goes through the interlock again.

Counters (telemetry): `switchings` per axis, relay operations (each closing and each opening:
the figure a relay's rated life is counted in); `chatter`, closings that come within
`trk_chatter_s` of the axis's previous opening (in either direction: the relay flickering,
a symptom of a too-narrow deadband or hysteresis, or a dial set too high); `reversals`,
closings opposite to the axis's previous closing (hunting: the report's "fluctuating from
leading then lagging"); `refusals`, interlock refusals (DIAL_NOT_LOW).

Sun-rate feed-forward (beyond the report; parameter `trk_ff` = 1, in sensor mode). The
controller knows the UTC date-time from `SetClock` (POSIX seconds, carried on by its own
monotonic clock; never set: NO_CLOCK) and the site from parameters (`trk_lat_deg`,
`trk_lon_deg`, `trk_press_hpa`, `trk_air_temp_c`; Tucson by default), and computes the sun's
position and its azimuth and elevation rates once a second with its own ephemeris
(`firmware_py/ephemeris.py`, NOAA's algorithm), extrapolating linearly in between. Per axis
the commanded rate is

    w = w_sun + e / tau         (deg/s; tau = `trk_ff_tau_s`)

where e is the pointing error the photocells measure: for two cells at +-45 deg from the
focal axis (the report's right-angled pair) (a - b) / (a + b) = tan(error) for the direct
beam, so e = atan(d / s) (d, s: the filtered difference and sum; the diffuse light in s
makes e read about 5 % small, which a proportional correction does not mind); for azimuth
the error across the beam is divided by cos(the tracker's elevation) (floored at 0.1) to
give the azimuth angle to turn. e is low-passed again at tau / 30 (1 s by default): the
correction loop's bandwidth is 1 / tau, so this costs it about 2 deg of phase and takes the
cells' noise (1 mV rms a cell, about 0.1 deg of azimuth error a sample in the morning) out
of the relays' decisions. Without a sun in the cells (sum below `trk_sun_min_v`) the
correction is 0 and the feed-forward alone carries the axis through the cloud. The relays
follow the sign of w, with hysteresis on |w| (close above 0.02 deg/min, open below 0.007
deg/min; the sun's azimuth rate at Tucson in June is 0.11 deg/min at its slowest,
mid-morning and late afternoon, and the elevation rate passes through 0 at transit) and the
same dwell; the duty is the one that
gives |w| by the firmware's model of the drive (`TrackerDrive`, below), at the 90 V bus
voltage TRACKER_POS measures, capped by the dial (the dial stays the operator's speed
limit). So the axis runs at the sun's speed
instead of stopping and starting (it neither lags, the feed-forward supplies the rate, nor
hunts, the correction is proportional and small), and a model error only leaves a steady
error of (rate error) x tau. Sun below the horizon: the feed-forward holds the axis
(SUN_DOWN). `trk_ff` = 1 without a clock runs the relay logic and says so (FF_FALLBACK).
Why a model and not online learning of the duty per deg/s: the potentiometers are noisy
(about 0.02 deg a sample) against the 0.1-1.5 deg/min the axes move, so an estimate of the
axis rate needs tens of seconds of travel, and the proportional correction already removes
what the model gets wrong; measured in tests/test_tracker_control.py.

Staleness. The tracker's inputs are its own business, never the supervisor's: a missing or
stale TRACKER_SENSE (no frame for `trk_stale_s`, 0.1 s = ten periods) stops sensor-mode drive
(SENSE_STALE), a stale TRACKER_POS all drive (POS_STALE: the limit switches are unknown);
neither latches a fault nor touches the arm, and the tracker resumes when the frames return
(a closing still waits out its dwell). On a plant without the tracker the controller runs as
before: the sensor logic never drives, and TRACKER_CMD (safe unless the box is switched on)
goes out every 10 ms to nobody.

The control box's temperature (report: keep the controller between -10 C and 45 C; the
supervisor faults outside `temp_min_c`/`temp_max_c`): `TempWatch` raises a warning within
`temp_warn_c` of either limit (TEMP_LOW / TEMP_HIGH in telemetry, and one TemperatureWarning
event per crossing each way), cleared 0.5 C back inside (hysteresis, so noise on the
0.1 C reading does not flood the link with events).
"""
