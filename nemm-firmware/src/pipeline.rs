//! One sample period of the estimator, board-independent: read the stroke sensor (velocity
//! and position), step the estimator, classify what went wrong. The firmware's 10 kHz task
//! calls [`run_period`]; the host tests call the same function over the same recording to
//! get the reference the target's output must match bit for bit.
//!
//! In the bench-controller mode ([`observe_period`], after [`run_period`] in the same
//! period) the load cell is read too, and the alpha observer gets the same velocity and
//! position as the estimator and the measured force.
//!
//! Faults never stop the loop: a failed or invalid sensor read is counted and flagged, and the
//! estimator is fed NaN, on which it holds its last good input (and flags that too).
//!
//! [`ChunkDigest`] condenses the periods' results into CRC-32s, one per
//! [`DIGEST_CHUNK_STEPS`] periods. The 10 kHz task computes them as it goes, so the host
//! can check every estimate even when the logger had to drop records (its queue full because
//! the step left it no time).

use crate::loadcell::{LoadCell, LoadCellError};
use crate::report::{ObserverRecord, FW_PRIMING, FW_SAMPLE_INVALID, FW_SENSOR_ERROR};
use crate::sensor::{SensorError, StrokeSensor};
use embedded_hal::spi::SpiDevice;
use nemm_core::{AlphaEstimate, Estimate, Estimator, Flags, Sample};

/// Sensor-path fault counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SensorCounters {
    /// Failed SPI transactions and "no new conversion" answers.
    pub sensor_errors: u32,
    /// Conversions the ADC flagged invalid, and non-finite velocities.
    pub invalid_samples: u32,
    /// Periods in which the differentiator was re-priming (start-up, after every fault).
    pub priming: u32,
}

/// What one period produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PeriodOutput {
    /// Velocity handed to the estimator \[m/s\]; NaN when the sensor path had none.
    pub velocity_m_s: f32,
    /// The estimator's output.
    pub estimate: Estimate,
    /// [`FW_SENSOR_ERROR`], [`FW_SAMPLE_INVALID`] or [`FW_PRIMING`] (at most one).
    pub firmware_flags: u8,
}

/// Reads one sample and steps the estimator.
#[inline(always)]
pub fn run_period<SPI: SpiDevice, const P: usize, const T: usize>(
    sensor: &mut StrokeSensor<SPI>,
    estimator: &mut Estimator<P, T>,
    counters: &mut SensorCounters,
) -> PeriodOutput {
    let (velocity_m_s, firmware_flags) = match sensor.read_velocity() {
        Ok(v) if v.is_finite() => (v, 0),
        Ok(_) | Err(SensorError::Invalid) => {
            counters.invalid_samples = counters.invalid_samples.wrapping_add(1);
            (f32::NAN, FW_SAMPLE_INVALID)
        }
        Err(SensorError::Priming) => {
            counters.priming = counters.priming.wrapping_add(1);
            (f32::NAN, FW_PRIMING)
        }
        Err(SensorError::Bus(_) | SensorError::NotReady) => {
            counters.sensor_errors = counters.sensor_errors.wrapping_add(1);
            (f32::NAN, FW_SENSOR_ERROR)
        }
    };
    // NaN in: the estimator holds its last good input and flags the step. The position
    // feeds a model's static force (NaN: the last good position, flagged); models without
    // one ignore it.
    let sample = Sample::new(velocity_m_s).with_position(sensor.position_m());
    // A sample without a level is never refused: the other arm is never taken.
    let estimate = estimator.step(sample).unwrap_or(Estimate {
        force_n: 0.0,
        flags: Flags(Flags::NO_MODEL),
    });
    PeriodOutput {
        velocity_m_s,
        estimate,
        firmware_flags,
    }
}

/// Load-cell fault counters (bench-controller mode).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LoadCellCounters {
    /// Failed SPI transactions and "no new conversion" answers.
    pub errors: u32,
    /// Conversions the ADC flagged invalid.
    pub invalid: u32,
    /// Conversions at full scale (the force beyond the channel's range).
    pub saturated: u32,
}

/// What the observer part of one period produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObservedOutput {
    /// The load cell's force handed to the observer \[N\]; NaN when the channel had none
    /// (the observer skips the sample, flag `FORCE_FAULT`).
    pub measured_force_n: f32,
    /// The observer's output.
    pub estimate: AlphaEstimate,
}

/// Reads the load cell and steps the observer with the period's velocity (NaN when the
/// stroke sensor had none: the observer's levels hold their input, flag `VELOCITY_FAULT`),
/// the sample's stroke position and the measured force. Call after [`run_period`] of the
/// same period, with `position_m` the stroke sensor's position of that sample.
#[inline(always)]
pub fn observe_period<SPI: SpiDevice>(
    load_cell: &mut LoadCell<SPI>,
    observer: &mut crate::FwObserver,
    period: &PeriodOutput,
    position_m: f32,
    counters: &mut LoadCellCounters,
) -> ObservedOutput {
    let measured_force_n = match load_cell.read_force() {
        Ok(f) => f,
        Err(LoadCellError::Bus(_) | LoadCellError::NotReady) => {
            counters.errors = counters.errors.wrapping_add(1);
            f32::NAN
        }
        Err(LoadCellError::Invalid) => {
            counters.invalid = counters.invalid.wrapping_add(1);
            f32::NAN
        }
        Err(LoadCellError::Saturated) => {
            counters.saturated = counters.saturated.wrapping_add(1);
            f32::NAN
        }
    };
    let sample = Sample::new(period.velocity_m_s)
        .with_position(position_m)
        .with_force(measured_force_n);
    let estimate = observer.step(sample);
    ObservedOutput {
        measured_force_n,
        estimate,
    }
}

/// Periods per digest chunk.
pub const DIGEST_CHUNK_STEPS: u32 = 1000;

/// Firmware flags that depend only on the recording and the options (not on timing), the
/// ones a digest covers.
pub const DETERMINISTIC_FLAGS: u8 = FW_SENSOR_ERROR | FW_SAMPLE_INVALID | FW_PRIMING;

/// CRC-32/ISO-HDLC (the zlib CRC-32, as the weight format's).
static CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Running CRC-32 over the periods of one chunk. Each period adds 10 bytes: the velocity's
/// and the force's `f32` bits (little-endian), the estimator flags and the deterministic
/// firmware flags ([`DETERMINISTIC_FLAGS`]); with the observer 13 more
/// ([`ChunkDigest::push_observed`]).
#[derive(Clone)]
pub struct ChunkDigest {
    digest: crc::Digest<'static, u32>,
    steps: u32,
}

impl ChunkDigest {
    /// An empty chunk.
    pub fn new() -> Self {
        Self {
            digest: CRC32.digest(),
            steps: 0,
        }
    }

    /// Adds one period.
    #[inline(always)]
    pub fn push(&mut self, out: &PeriodOutput) {
        let v = out.velocity_m_s.to_bits().to_le_bytes();
        let f = out.estimate.force_n.to_bits().to_le_bytes();
        let [v0, v1, v2, v3] = v;
        let [f0, f1, f2, f3] = f;
        self.digest.update(&[
            v0,
            v1,
            v2,
            v3,
            f0,
            f1,
            f2,
            f3,
            out.estimate.flags.0,
            out.firmware_flags & DETERMINISTIC_FLAGS,
        ]);
        self.steps += 1;
    }

    /// Adds the observer part of the period last [`pushed`](ChunkDigest::push): the
    /// measured force's, the estimate's and the band's `f32` bits (little-endian) and the
    /// observer's flags.
    #[inline(always)]
    pub fn push_observed(&mut self, out: &ObservedOutput) {
        let [m0, m1, m2, m3] = out.measured_force_n.to_bits().to_le_bytes();
        let [a0, a1, a2, a3] = out.estimate.alpha.to_bits().to_le_bytes();
        let [b0, b1, b2, b3] = out.estimate.band.to_bits().to_le_bytes();
        self.digest.update(&[
            m0,
            m1,
            m2,
            m3,
            a0,
            a1,
            a2,
            a3,
            b0,
            b1,
            b2,
            b3,
            out.estimate.flags.0,
        ]);
    }

    /// Periods added since the last [`ChunkDigest::finish`].
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// The chunk's CRC; starts the next chunk.
    pub fn finish(&mut self) -> u32 {
        self.steps = 0;
        core::mem::replace(&mut self.digest, CRC32.digest()).finalize()
    }
}

impl Default for ChunkDigest {
    fn default() -> Self {
        Self::new()
    }
}

impl core::fmt::Debug for ChunkDigest {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ChunkDigest")
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

/// The digest of a whole run: CRC-32 over the chunk CRCs (little-endian, in order).
pub fn run_digest(chunks: impl IntoIterator<Item = u32>) -> u32 {
    let mut d = CRC32.digest();
    for c in chunks {
        d.update(&c.to_le_bytes());
    }
    d.finalize()
}

/// The observer's part of a step's record line.
impl From<&ObservedOutput> for ObserverRecord {
    fn from(o: &ObservedOutput) -> Self {
        Self {
            measured_force_n: o.measured_force_n,
            alpha: o.estimate.alpha,
            band: o.estimate.band,
            flags: o.estimate.flags.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn out(v: f32, f: f32, ef: u8, ff: u8) -> PeriodOutput {
        PeriodOutput {
            velocity_m_s: v,
            estimate: Estimate {
                force_n: f,
                flags: Flags(ef),
            },
            firmware_flags: ff,
        }
    }

    #[test]
    fn digest_is_the_crc_of_the_records_and_ignores_timing_flags() {
        let mut d = ChunkDigest::new();
        d.push(&out(1.0, -2.0, 5, FW_PRIMING | crate::report::FW_OVERRUN));
        assert_eq!(d.steps(), 1);
        let mut bytes = std::vec::Vec::new();
        bytes.extend_from_slice(&1.0f32.to_bits().to_le_bytes());
        bytes.extend_from_slice(&(-2.0f32).to_bits().to_le_bytes());
        bytes.extend_from_slice(&[5, FW_PRIMING]);
        assert_eq!(d.finish(), nemm_core::CRC.checksum(&bytes));
        assert_eq!(d.steps(), 0);
        // A fresh chunk after finish.
        let empty = ChunkDigest::new().finish();
        assert_eq!(d.finish(), empty);
        let mut all = std::vec::Vec::new();
        all.extend_from_slice(&7u32.to_le_bytes());
        all.extend_from_slice(&9u32.to_le_bytes());
        assert_eq!(run_digest([7, 9]), nemm_core::CRC.checksum(&all));
    }

    #[test]
    fn the_observer_part_extends_the_period() {
        let mut d = ChunkDigest::new();
        d.push(&out(1.0, -2.0, 0, 0));
        d.push_observed(&ObservedOutput {
            measured_force_n: 3.0,
            estimate: AlphaEstimate {
                alpha: 0.25,
                band: 0.5,
                force_n: 99.0,
                flags: nemm_core::ObserverFlags(0x21),
            },
        });
        assert_eq!(d.steps(), 1, "one period");
        let mut bytes = std::vec::Vec::new();
        for v in [1.0f32, -2.0] {
            bytes.extend_from_slice(&v.to_bits().to_le_bytes());
        }
        bytes.extend_from_slice(&[0, 0]);
        for v in [3.0f32, 0.25, 0.5] {
            bytes.extend_from_slice(&v.to_bits().to_le_bytes());
        }
        bytes.push(0x21);
        assert_eq!(d.finish(), nemm_core::CRC.checksum(&bytes));
    }
}
