//! Raw counts and volts to SI units (bench-model.md §8), the tare of the torque channels and
//! the plausibility limits of every raw channel.
//!
//! * Encoders: `theta = counts * 2 pi / (N G)` at the output axis, `N` counts per motor
//!   revolution after x4 decoding (parameter `encoderCountsPerRevolution`), `G` the gear ratio
//!   (`i_HD` on the actuation side, `i_RED` on the load side). Counts are taken relative to the
//!   count at initialization and unwrapped across the 32-bit counter's overflow.
//! * Torque transducer and load cell: the published pendulum calibration
//!   `V = a + b sin(theta + c)`, `T = m g Lg sin(theta)`, inverted as
//!   `T = (m g Lg / b)(V - a0)` with `a0` the **tared** zero: the mean of `tareSamples` readings
//!   taken at initialization with both drivers disabled and the clutch released (the bench
//!   unloaded). Without a tare (`tareSamples` = 0) `a0 = a`, the published offset. A tare
//!   removes the `m g Lg sin(c)` bias the published formula carries (-0.048 N m transducer,
//!   +0.090 N m load cell); the gain error `cos(c)` (5e-5, 1.8e-4) remains.
//! * Supply dividers: `V_supply = (V - 0.002) / 0.139`.
//! * Current sensors (ACS712-20A): `i = (V - 2.5 V) / 0.1 V/A`.
//! * Plausibility: every analog channel has a window of raw volts; an encoder may not move
//!   faster than `maxEncoderSpeed` at the output. A reading outside is a sensor fault and trips.

use super::protocol::{ANALOG_CHANNELS, AnalogChannel, Sample};
use crate::models::bench::BenchParameters;

/// Which shaft side an encoder is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// Test motor, behind the harmonic drive.
    Actuation,
    /// Load motor, behind the planetary gearbox.
    Load,
}

/// The calibration of every channel, with the tared zeros of the torque channels.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// Encoder counts per motor revolution (x4 decoded).
    pub counts_per_revolution: f64,
    /// Gear ratios (actuation, load).
    pub ratios: [f64; 2],
    /// Transducer (a, b) \[V\].
    pub transducer: (f64, f64),
    /// Load cell (a, b) \[V\].
    pub load_cell: (f64, f64),
    /// Pendulum moment m g Lg [N m].
    pub moment: f64,
    /// Divider offset \[V\] and gain.
    pub divider: (f64, f64),
    /// Current sensor offset \[V\] and sensitivity [V/A].
    pub current_sensor: (f64, f64),
    /// Zero of the transducer \[V\]: `a`, or the tared mean.
    pub transducer_zero: f64,
    /// Zero of the load cell \[V\].
    pub load_cell_zero: f64,
}

impl Calibration {
    /// The published calibration of `p`, untared.
    pub fn new(p: &BenchParameters) -> Self {
        Self {
            counts_per_revolution: p.encoder_counts_per_revolution,
            ratios: [p.harmonic_drive_ratio, p.reduction_ratio],
            transducer: (p.transducer_offset, p.transducer_gain),
            load_cell: (p.load_cell_offset, p.load_cell_gain),
            moment: p.calibration_pendulum_moment,
            divider: (p.divider_offset, p.divider_gain),
            current_sensor: (p.current_sensor_offset, p.current_sensor_sensitivity),
            transducer_zero: p.transducer_offset,
            load_cell_zero: p.load_cell_offset,
        }
    }

    fn counts_per_radian(&self, side: Side) -> f64 {
        let ratio = match side {
            Side::Actuation => self.ratios[0],
            Side::Load => self.ratios[1],
        };
        self.counts_per_revolution * ratio / std::f64::consts::TAU
    }

    /// Output-axis angle \[rad\] of a (relative, unwrapped) count.
    pub fn angle(&self, side: Side, counts: i64) -> f64 {
        counts as f64 / self.counts_per_radian(side)
    }

    /// The count an incremental encoder shows at output angle `theta` (floor quantisation).
    pub fn counts(&self, side: Side, theta: f64) -> i64 {
        (theta * self.counts_per_radian(side)).floor() as i64
    }

    /// One count at the output axis \[rad\].
    pub fn resolution(&self, side: Side) -> f64 {
        1.0 / self.counts_per_radian(side)
    }

    /// Transducer torque [N m] of a raw voltage.
    pub fn transducer_torque(&self, volts: f64) -> f64 {
        self.moment / self.transducer.1 * (volts - self.transducer_zero)
    }

    /// The raw voltage that reads as `torque` (inverse of [`Self::transducer_torque`]).
    pub fn transducer_volts(&self, torque: f64) -> f64 {
        self.transducer_zero + self.transducer.1 * torque / self.moment
    }

    /// Load-cell torque [N m] of a raw voltage.
    pub fn load_cell_torque(&self, volts: f64) -> f64 {
        self.moment / self.load_cell.1 * (volts - self.load_cell_zero)
    }

    /// The raw voltage that reads as `torque`.
    pub fn load_cell_volts(&self, torque: f64) -> f64 {
        self.load_cell_zero + self.load_cell.1 * torque / self.moment
    }

    /// Supply voltage \[V\] of a divider reading.
    pub fn supply_voltage(&self, volts: f64) -> f64 {
        (volts - self.divider.0) / self.divider.1
    }

    /// Divider reading for a supply voltage.
    pub fn divider_volts(&self, supply: f64) -> f64 {
        self.divider.0 + self.divider.1 * supply
    }

    /// Motor current \[A\] of a current-sensor reading.
    pub fn current(&self, volts: f64) -> f64 {
        (volts - self.current_sensor.0) / self.current_sensor.1
    }

    /// Current-sensor reading for a current.
    pub fn current_volts(&self, current: f64) -> f64 {
        self.current_sensor.0 + self.current_sensor.1 * current
    }

    /// Sets the torque channels' zeros from a completed tare.
    pub fn apply_tare(&mut self, tare: &Tare) {
        if let Some((transducer, load_cell)) = tare.means() {
            self.transducer_zero = transducer;
            self.load_cell_zero = load_cell;
        }
    }
}

/// Averages the torque channels over samples taken with the drivers disabled.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Tare {
    sums: [f64; 2],
    count: u32,
}

impl Tare {
    /// Adds one sample.
    pub fn add(&mut self, sample: &Sample) {
        self.sums[0] += sample.analog[AnalogChannel::Transducer.index()];
        self.sums[1] += sample.analog[AnalogChannel::LoadCell.index()];
        self.count += 1;
    }

    /// Samples added.
    pub fn count(&self) -> u32 {
        self.count
    }

    /// (transducer, load cell) mean voltages, `None` before the first sample.
    pub fn means(&self) -> Option<(f64, f64)> {
        (self.count > 0).then(|| {
            let n = f64::from(self.count);
            (self.sums[0] / n, self.sums[1] / n)
        })
    }
}

/// A raw reading outside its plausible range.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SensorFault {
    /// An analog channel outside its window.
    #[error("{} reads {volts} V, outside {min}..{max} V", channel.name())]
    Analog {
        /// The channel.
        channel: AnalogChannel,
        /// The reading.
        volts: f64,
        /// Window.
        min: f64,
        /// Window.
        max: f64,
    },
    /// An encoder moved faster than physically possible.
    #[error("{side:?} encoder moved {counts} counts in {dt} s (more than {max_speed} rad/s)")]
    Encoder {
        /// The side.
        side: Side,
        /// The movement.
        counts: i64,
        /// Over this time.
        dt: f64,
        /// The plausible speed.
        max_speed: f64,
    },
}

/// Plausibility windows of the raw channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausibility {
    /// (min, max) raw volts per [`AnalogChannel`].
    pub analog: [(f64, f64); ANALOG_CHANNELS],
    /// The fastest an output axis can turn [rad/s].
    pub max_speed: f64,
}

impl Default for Plausibility {
    fn default() -> Self {
        Plausibility::DEFAULT
    }
}

impl Plausibility {
    /// The default windows, derived for the published calibration (module docs of the FMU).
    pub const DEFAULT: Plausibility = Plausibility {
        analog: [
            (5.40, 5.46),
            (0.15, 0.35),
            (0.25, 4.75),
            (0.25, 4.75),
            (2.504, 4.172),
            (5.562, 7.786),
        ],
        max_speed: 20.0,
    };

    /// Checks the analog channels of `sample`.
    pub fn check_analog(&self, sample: &Sample) -> Result<(), SensorFault> {
        for channel in AnalogChannel::ALL {
            let volts = sample.analog[channel.index()];
            let (min, max) = self.analog[channel.index()];
            if !(min..=max).contains(&volts) {
                return Err(SensorFault::Analog {
                    channel,
                    volts,
                    min,
                    max,
                });
            }
        }
        Ok(())
    }

    /// Checks an encoder movement of `counts` over `dt` seconds (one count of slack).
    pub fn check_encoder(
        &self,
        calibration: &Calibration,
        side: Side,
        counts: i64,
        dt: f64,
    ) -> Result<(), SensorFault> {
        let allowed = self.max_speed * dt / calibration.resolution(side) + 1.0;
        if (counts.unsigned_abs() as f64) > allowed {
            return Err(SensorFault::Encoder {
                side,
                counts,
                dt,
                max_speed: self.max_speed,
            });
        }
        Ok(())
    }
}

/// Unwraps a wrapping 32-bit counter into a 64-bit count relative to its first reading.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Unwrapper {
    last: Option<i32>,
    total: i64,
}

impl Unwrapper {
    /// Feeds a raw counter value; returns the count since the first one.
    pub fn update(&mut self, raw: i32) -> i64 {
        if let Some(last) = self.last {
            self.total += i64::from(raw.wrapping_sub(last));
        }
        self.last = Some(raw);
        self.total
    }

    /// The count since the first reading.
    pub fn total(&self) -> i64 {
        self.total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cal() -> Calibration {
        Calibration::new(&BenchParameters::default())
    }

    #[test]
    fn encoder_round_trip_within_one_count() {
        let c = cal();
        for side in [Side::Actuation, Side::Load] {
            for k in -2000..2000 {
                let theta = k as f64 * 1.2345e-3;
                let back = c.angle(side, c.counts(side, theta));
                assert!(back <= theta + 1e-15 && theta - back < c.resolution(side));
            }
        }
        assert!((c.resolution(Side::Actuation) - 1.963495e-5).abs() < 1e-11);
        assert!((c.resolution(Side::Load) - 4.759989e-5).abs() < 1e-11);
    }

    #[test]
    fn analog_round_trips_si_to_raw_to_si() {
        let mut c = cal();
        for k in -40..=40 {
            let torque = k as f64 * 0.5;
            assert!((c.transducer_torque(c.transducer_volts(torque)) - torque).abs() < 1e-12);
            assert!((c.load_cell_torque(c.load_cell_volts(torque)) - torque).abs() < 1e-9);
            let current = k as f64 * 0.4;
            assert!((c.current(c.current_volts(current)) - current).abs() < 1e-12);
            let supply = 20.0 + k as f64 * 0.1;
            assert!((c.supply_voltage(c.divider_volts(supply)) - supply).abs() < 1e-12);
        }
        // With a tare the round trip holds around the new zero too.
        let mut tare = Tare::default();
        let mut s = Sample::default();
        s.analog[AnalogChannel::Transducer.index()] = 0.2451;
        s.analog[AnalogChannel::LoadCell.index()] = 5.4302;
        tare.add(&s);
        c.apply_tare(&tare);
        assert_eq!(c.transducer_zero, 0.2451);
        assert!((c.transducer_torque(c.transducer_volts(7.5)) - 7.5).abs() < 1e-12);
        assert!(c.transducer_torque(0.2451).abs() < 1e-15);
    }

    #[test]
    fn tare_removes_the_published_bias() {
        // The bench's sensor model: V = a + b sin(c) + b cos(c) T / (m g Lg).
        let p = BenchParameters::default();
        let raw = |t: f64| {
            p.transducer_offset
                + p.transducer_gain * p.transducer_phase.sin()
                + p.transducer_gain * p.transducer_phase.cos() * t / p.calibration_pendulum_moment
        };
        let mut c = cal();
        assert!((c.transducer_torque(raw(0.0)) - (-0.0475)).abs() < 1e-3);
        let mut tare = Tare::default();
        for _ in 0..10 {
            let mut s = Sample::default();
            s.analog[AnalogChannel::Transducer.index()] = raw(0.0);
            tare.add(&s);
        }
        c.apply_tare(&tare);
        assert!(c.transducer_torque(raw(0.0)).abs() < 1e-12);
        let t = 10.0;
        assert!((c.transducer_torque(raw(t)) - t * p.transducer_phase.cos()).abs() < 1e-9);
    }

    #[test]
    fn plausibility_windows_hold_the_default_bench_at_rest_and_reject_rails() {
        let p = BenchParameters::default();
        let c = cal();
        let mut s = Sample::default();
        s.analog[AnalogChannel::LoadCell.index()] = c.load_cell_volts(0.0);
        s.analog[AnalogChannel::Transducer.index()] = c.transducer_volts(0.0);
        s.analog[AnalogChannel::TestCurrentSense.index()] = c.current_volts(0.0);
        s.analog[AnalogChannel::LoadCurrentSense.index()] = c.current_volts(0.0);
        s.analog[AnalogChannel::TestSupplySense.index()] = c.divider_volts(p.test_supply_voltage);
        s.analog[AnalogChannel::LoadSupplySense.index()] = c.divider_volts(p.load_supply_voltage);
        let w = Plausibility::DEFAULT;
        assert_eq!(w.check_analog(&s), Ok(()));
        for channel in AnalogChannel::ALL {
            for rail in [0.0, 10.0] {
                let mut bad = s;
                bad.analog[channel.index()] = rail;
                assert!(matches!(
                    w.check_analog(&bad),
                    Err(SensorFault::Analog { channel: ch, .. }) if ch == channel
                ));
            }
        }
        // 40 N m on either torque channel is still plausible (twice the interlock).
        s.analog[AnalogChannel::Transducer.index()] = c.transducer_volts(40.0);
        s.analog[AnalogChannel::LoadCell.index()] = c.load_cell_volts(-40.0);
        assert_eq!(w.check_analog(&s), Ok(()));
        assert!(w.check_encoder(&c, Side::Actuation, 1000, 1e-3).is_ok());
        assert!(w.check_encoder(&c, Side::Actuation, 1100, 1e-3).is_err());
    }

    #[test]
    fn counters_unwrap_across_overflow() {
        let mut u = Unwrapper::default();
        assert_eq!(u.update(i32::MAX - 1), 0);
        assert_eq!(u.update(i32::MIN + 1), 3);
        assert_eq!(u.update(i32::MAX), 1);
    }
}
