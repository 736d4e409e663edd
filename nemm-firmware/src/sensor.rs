//! Stroke-velocity sensor path: a displacement transducer behind a 24-bit SPI ADC, read
//! through `embedded-hal` 1.0 [`SpiDevice`], differentiated to velocity in m/s.
//!
//! # The ADC frame
//!
//! The driver talks to an ADC that appends its status byte to every conversion result
//! (modelled on the `DATA_STAT` mode of 24-bit converters such as the AD717x family). One
//! read is one SPI transaction:
//!
//! ```text
//! MOSI: 0x44 (read the data register)
//! MISO:            D[23:16] D[15:8] D[7:0] STATUS
//! ```
//!
//! - `D` is the result in offset binary: code `0x800000` is zero displacement, one LSB is
//!   [`Calibration::metres_per_lsb`] (positive = extension, the estimator's sign).
//! - `STATUS` bit 7 ([`STATUS_NOT_READY`]) set: no new conversion since the last read;
//!   bit 6 ([`STATUS_ADC_ERROR`]) set: the conversion is invalid (over/under-range, sensor
//!   open). Both make the sample unusable.
//!
//! A different converter only needs [`READ_DATA_COMMAND`], [`Frame::decode`] and the
//! calibration changed; the filter and the fault handling stay.
//!
//! # Differentiation filter
//!
//! The paper's bench computes velocity by numerical differentiation of the measured stroke
//! (section 3). Here the codes go through [`nemm_core::Differentiator`]: a
//! backward difference of the integer codes (exact) times `metres_per_lsb * fs`, followed by
//! a first-order low-pass (backward-Euler RC, corner [`Calibration::cutoff_hz`], default
//! [`DEFAULT_CUTOFF_HZ`]: 0.37 ms of group delay at 10 kHz, 4 degrees of phase at 30 Hz; see
//! that module for the formulas). The trainer's `--velocity causal` preprocessing runs the
//! same filter. 0.5 um RMS displacement noise becomes about 3 mm/s RMS of velocity noise.
//!
//! After a failed or invalid sample the difference is undefined: the next good sample only
//! re-primes the filter ([`SensorError::Priming`]), and the sample after it seeds the
//! low-pass with its raw difference (no transient from stale filter state).

use crate::adc::{self, RawFrame};
pub use crate::adc::{STATUS_ADC_ERROR, STATUS_NOT_READY};
use embedded_hal::spi::SpiDevice;

/// Command byte that reads the conversion result with its status byte.
pub const READ_DATA_COMMAND: u8 = 0x44;
/// Result code of zero displacement (offset binary).
pub const ZERO_CODE: i32 = 0x80_0000;
/// Largest result code.
pub const MAX_CODE: i32 = 0xFF_FFFF;
pub use nemm_core::{Differentiator, DEFAULT_CUTOFF_HZ};

/// One conversion result as it arrives on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    /// 24-bit result, offset binary.
    pub code: i32,
    /// Status byte.
    pub status: u8,
}

impl Frame {
    /// Bytes as the ADC sends them after the command byte.
    pub fn encode(self) -> [u8; 4] {
        RawFrame {
            bits: self.code.clamp(0, MAX_CODE) as u32,
            status: self.status,
        }
        .encode()
    }

    /// Parses the four bytes after the command byte.
    pub fn decode(bytes: [u8; 4]) -> Self {
        Self::from(RawFrame::decode(bytes))
    }
}

impl From<RawFrame> for Frame {
    /// The 24 bits as an offset-binary code.
    fn from(raw: RawFrame) -> Self {
        Self {
            code: raw.bits as i32,
            status: raw.status,
        }
    }
}

/// Scale and rate of the stroke channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Displacement per ADC LSB \[m\] (full scale / 2^24).
    pub metres_per_lsb: f32,
    /// Sample rate \[Hz\]: the rate at which [`StrokeSensor::read_velocity`] is called.
    pub sample_rate_hz: f32,
    /// Corner frequency of the velocity low-pass \[Hz\].
    pub cutoff_hz: f32,
}

impl Calibration {
    /// Full scale `±full_scale_m` over the 24-bit range, sampled at `sample_rate_hz`, with
    /// the default low-pass corner.
    pub fn new(full_scale_m: f32, sample_rate_hz: f32) -> Self {
        Self {
            metres_per_lsb: 2.0 * full_scale_m / (1u32 << 24) as f32,
            sample_rate_hz,
            cutoff_hz: DEFAULT_CUTOFF_HZ,
        }
    }

    /// Displacement \[m\] of a result code.
    pub fn displacement_m(&self, code: i32) -> f32 {
        (code - ZERO_CODE) as f32 * self.metres_per_lsb
    }

    /// Result code of a displacement \[m\], rounded to the nearest LSB and clamped to the
    /// range; `None` if it is out of range or not finite (the ADC would flag it).
    pub fn code_of(&self, displacement_m: f32) -> Option<i32> {
        let lsb = f64::from(displacement_m) / f64::from(self.metres_per_lsb);
        if !lsb.is_finite() {
            return None;
        }
        // Round half away from zero without `f64::round` (not in `core`).
        let r = if lsb >= 0.0 { lsb + 0.5 } else { lsb - 0.5 };
        let code = r as i64 + i64::from(ZERO_CODE);
        if (0..=i64::from(MAX_CODE)).contains(&code) {
            Some(code as i32)
        } else {
            None
        }
    }
}

/// Why no velocity is available this period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SensorError<E> {
    /// The SPI transaction failed.
    Bus(E),
    /// The ADC had no new conversion (status bit 7).
    NotReady,
    /// The ADC flagged the conversion invalid (status bit 6): over/under-range, sensor open.
    Invalid,
    /// First good sample after start-up or after a fault: the filter needs one more sample.
    Priming,
}

/// Driver of the stroke channel on any [`SpiDevice`].
#[derive(Debug)]
pub struct StrokeSensor<SPI> {
    spi: SPI,
    cal: Calibration,
    diff: Differentiator,
    position_m: f32,
}

impl<SPI: SpiDevice> StrokeSensor<SPI> {
    /// Driver on `spi` with calibration `cal`.
    pub fn new(spi: SPI, cal: Calibration) -> Self {
        Self {
            spi,
            diff: Differentiator::new(cal.metres_per_lsb, cal.sample_rate_hz, cal.cutoff_hz),
            cal,
            position_m: f32::NAN,
        }
    }

    /// Reads one conversion frame (one SPI transaction).
    pub fn read_frame(&mut self) -> Result<Frame, SPI::Error> {
        adc::read_frame(&mut self.spi, READ_DATA_COMMAND).map(Frame::from)
    }

    /// Reads the next sample and returns the stroke velocity \[m/s\] (positive = extension).
    /// Call once per sample period. The sample's position is [`StrokeSensor::position_m`].
    pub fn read_velocity(&mut self) -> Result<f32, SensorError<SPI::Error>> {
        self.position_m = f32::NAN;
        let frame = match self.read_frame() {
            Ok(f) => f,
            Err(e) => {
                self.diff.invalidate();
                return Err(SensorError::Bus(e));
            }
        };
        if frame.status & STATUS_NOT_READY != 0 {
            self.diff.invalidate();
            return Err(SensorError::NotReady);
        }
        if frame.status & STATUS_ADC_ERROR != 0 {
            self.diff.invalidate();
            return Err(SensorError::Invalid);
        }
        self.position_m = self.cal.displacement_m(frame.code);
        self.diff.push(frame.code).ok_or(SensorError::Priming)
    }

    /// Stroke position \[m\] of the last [`StrokeSensor::read_velocity`], in the
    /// transducer's coordinates (zero at code `0x800000`): the input of a model's static
    /// force. NaN when that read gave no valid conversion (also while priming it is valid).
    pub fn position_m(&self) -> f32 {
        self.position_m
    }

    /// The calibration in use.
    pub fn calibration(&self) -> &Calibration {
        &self.cal
    }

    /// The SPI device (e.g. to ask a replay device whether its recording has ended).
    pub fn spi(&self) -> &SPI {
        &self.spi
    }

    /// Mutable access to the SPI device.
    pub fn spi_mut(&mut self) -> &mut SPI {
        &mut self.spi
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::spi::ErrorKind;
    use std::vec::Vec;

    use crate::adc::script::Script;

    fn frame(code: i32, status: u8) -> Result<[u8; 4], ErrorKind> {
        Ok(Frame { code, status }.encode())
    }

    #[test]
    fn frame_round_trip_and_byte_order() {
        let f = Frame {
            code: 0x12_3456,
            status: STATUS_ADC_ERROR,
        };
        assert_eq!(f.encode(), [0x12, 0x34, 0x56, 0x40]);
        assert_eq!(Frame::decode(f.encode()), f);
    }

    #[test]
    fn codes_round_trip_within_half_an_lsb() {
        let cal = Calibration::new(0.1, 10_000.0);
        for &x in &[0.0f32, 1e-6, -0.0312, 0.0499, -0.1 + 1e-6] {
            let c = cal.code_of(x).unwrap();
            assert!((cal.displacement_m(c) - x).abs() <= 0.5 * cal.metres_per_lsb + 1e-9);
        }
        assert_eq!(cal.code_of(0.2), None);
        assert_eq!(cal.code_of(f32::NAN), None);
        assert_eq!(cal.code_of(0.0), Some(ZERO_CODE));
    }

    #[test]
    fn constant_velocity_is_recovered_and_faults_reprime() {
        let cal = Calibration::new(0.1, 10_000.0);
        // 0.3 m/s = 30 um per sample.
        let step = cal.code_of(30e-6).unwrap() - ZERO_CODE;
        let mut frames = Vec::new();
        for n in 0..20 {
            frames.push(frame(ZERO_CODE + n * step, 0));
        }
        frames.push(Err(ErrorKind::Overrun));
        frames.push(frame(ZERO_CODE, STATUS_ADC_ERROR));
        frames.push(frame(ZERO_CODE, STATUS_NOT_READY));
        for n in 0..3 {
            frames.push(frame(ZERO_CODE - n * step, 0));
        }
        let mut s = StrokeSensor::new(
            Script {
                command: READ_DATA_COMMAND,
                frames,
                next: 0,
            },
            cal,
        );
        assert!(s.position_m().is_nan(), "no read yet");
        assert_eq!(s.read_velocity(), Err(SensorError::Priming));
        assert_eq!(s.position_m(), 0.0, "the priming sample has a position");
        let expected = step as f32 * cal.metres_per_lsb * cal.sample_rate_hz;
        for n in 1..20 {
            // Constant input: the low-pass is at its fixed point after the seed.
            assert_eq!(s.read_velocity(), Ok(expected));
            assert_eq!(s.position_m(), cal.displacement_m(ZERO_CODE + n * step));
        }
        assert!((expected - 0.3).abs() < 1e-3);
        assert_eq!(s.read_velocity(), Err(SensorError::Bus(ErrorKind::Overrun)));
        assert!(s.position_m().is_nan());
        assert_eq!(s.read_velocity(), Err(SensorError::Invalid));
        assert!(s.position_m().is_nan());
        assert_eq!(s.read_velocity(), Err(SensorError::NotReady));
        assert!(s.position_m().is_nan());
        assert_eq!(s.read_velocity(), Err(SensorError::Priming));
        assert_eq!(s.position_m(), 0.0);
        // Seeded with the raw difference of the new direction, no transient from before.
        assert_eq!(s.read_velocity(), Ok(-expected));
        assert_eq!(s.read_velocity(), Ok(-expected));
    }
}
