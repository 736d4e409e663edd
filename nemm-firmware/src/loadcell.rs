//! Load-cell channel: the damper force measured by a strain-gauge load cell behind a 24-bit
//! bridge ADC, read through `embedded-hal` 1.0 [`SpiDevice`] (a second SPI device beside the
//! stroke sensor's), converted to newtons. The bench-controller build feeds it, with the
//! stroke velocity, to the alpha observer (`observer=on`, see the crate's README).
//!
//! # The ADC frame
//!
//! Modelled on 24-bit bridge converters of the ADS1220 class, with a status byte appended
//! as the stroke channel's ADC sends it. One read is one SPI transaction:
//!
//! ```text
//! MOSI: 0x10 (RDATA: read the conversion result)
//! MISO:            D[23:16] D[15:8] D[7:0] STATUS
//! ```
//!
//! - `D` is the result in two's complement (code 0 is zero differential input; one LSB is
//!   [`Calibration::newtons_per_count`]; positive = tension, the observer's sign).
//! - `STATUS` bit 7 ([`STATUS_NOT_READY`]): no new conversion since the last read; bit 6
//!   ([`STATUS_ADC_ERROR`]): the conversion is invalid (bridge open or shorted, reference
//!   missing). Both make the sample unusable.
//! - A result at either end of the range ([`MAX_CODE`], [`MIN_CODE`]) means the input
//!   drove the converter to full scale: the true force is beyond what the channel
//!   measures. Such a sample is refused as [`LoadCellError::Saturated`], not clipped.
//!
//! # Calibration
//!
//! `force = (code - offset_counts) * newtons_per_count`: the gain from the load cell's
//! sensitivity, the bridge excitation and the converter's gain and reference (or from a
//! dead-weight calibration), the offset the converter's reading at zero load (tare).
//!
//! # Faults
//!
//! Every error is returned, never held: the caller hands the observer NaN, which flags the
//! sample [`nemm_core::ObserverFlags::FORCE_FAULT`] and skips it. The force path has no
//! state, so the next good sample is used as it is.

use crate::adc::{self, RawFrame};
pub use crate::adc::{STATUS_ADC_ERROR, STATUS_NOT_READY};
use embedded_hal::spi::SpiDevice;

/// Command byte that reads the conversion result (ADS1220's `RDATA`).
pub const READ_DATA_COMMAND: u8 = 0x10;
/// Largest result code (positive full scale).
pub const MAX_CODE: i32 = 0x7F_FFFF;
/// Smallest result code (negative full scale).
pub const MIN_CODE: i32 = -0x80_0000;

/// One conversion result as it arrives on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    /// 24-bit result, sign-extended.
    pub code: i32,
    /// Status byte.
    pub status: u8,
}

impl Frame {
    /// Bytes as the ADC sends them after the command byte (the code clamped to the range).
    pub fn encode(self) -> [u8; 4] {
        RawFrame {
            bits: (self.code.clamp(MIN_CODE, MAX_CODE) as u32) & 0xFF_FFFF,
            status: self.status,
        }
        .encode()
    }

    /// Parses the four bytes after the command byte.
    pub fn decode(bytes: [u8; 4]) -> Self {
        Self::from(RawFrame::decode(bytes))
    }

    /// True if the code is at either end of the range.
    pub fn saturated(self) -> bool {
        self.code >= MAX_CODE || self.code <= MIN_CODE
    }
}

impl From<RawFrame> for Frame {
    /// The 24 bits as a two's-complement code (bit 23 sign-extended).
    fn from(raw: RawFrame) -> Self {
        Self {
            code: ((raw.bits << 8) as i32) >> 8,
            status: raw.status,
        }
    }
}

/// Gain and offset of the load-cell channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Force per ADC count \[N\].
    pub newtons_per_count: f32,
    /// Reading at zero load \[counts\].
    pub offset_counts: i32,
}

impl Calibration {
    /// Full scale `±full_scale_n` over the 24-bit range, zero load read as `offset_counts`.
    pub fn new(full_scale_n: f32, offset_counts: i32) -> Self {
        Self {
            newtons_per_count: full_scale_n / (1u32 << 23) as f32,
            offset_counts,
        }
    }

    /// Force \[N\] of a result code.
    pub fn force_n(&self, code: i32) -> f32 {
        code.saturating_sub(self.offset_counts) as f32 * self.newtons_per_count
    }

    /// Result code of a force \[N\], rounded to the nearest count; `None` if it is not
    /// finite. Forces beyond the range give the code at the end of the range (the
    /// converter saturates).
    pub fn code_of(&self, force_n: f32) -> Option<i32> {
        let counts = f64::from(force_n) / f64::from(self.newtons_per_count);
        if !counts.is_finite() {
            return None;
        }
        // Round half away from zero without `f64::round` (not in `core`).
        let r = if counts >= 0.0 {
            counts + 0.5
        } else {
            counts - 0.5
        };
        let code = (r as i64).saturating_add(i64::from(self.offset_counts));
        Some(code.clamp(i64::from(MIN_CODE), i64::from(MAX_CODE)) as i32)
    }
}

/// Why no force is available this period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoadCellError<E> {
    /// The SPI transaction failed.
    Bus(E),
    /// The ADC had no new conversion (status bit 7).
    NotReady,
    /// The ADC flagged the conversion invalid (status bit 6).
    Invalid,
    /// The result is at full scale: the force is beyond the channel's range.
    Saturated,
}

/// Driver of the load-cell channel on any [`SpiDevice`].
#[derive(Debug)]
pub struct LoadCell<SPI> {
    spi: SPI,
    cal: Calibration,
}

impl<SPI: SpiDevice> LoadCell<SPI> {
    /// Driver on `spi` with calibration `cal`.
    pub fn new(spi: SPI, cal: Calibration) -> Self {
        Self { spi, cal }
    }

    /// Reads one conversion frame (one SPI transaction).
    pub fn read_frame(&mut self) -> Result<Frame, SPI::Error> {
        adc::read_frame(&mut self.spi, READ_DATA_COMMAND).map(Frame::from)
    }

    /// Reads the next sample and returns the force \[N\] (positive = tension). Call once per
    /// sample period, in the same period as the stroke sensor's read.
    pub fn read_force(&mut self) -> Result<f32, LoadCellError<SPI::Error>> {
        let frame = self.read_frame().map_err(LoadCellError::Bus)?;
        if frame.status & STATUS_NOT_READY != 0 {
            return Err(LoadCellError::NotReady);
        }
        if frame.status & STATUS_ADC_ERROR != 0 {
            return Err(LoadCellError::Invalid);
        }
        if frame.saturated() {
            return Err(LoadCellError::Saturated);
        }
        Ok(self.cal.force_n(frame.code))
    }

    /// The calibration in use.
    pub fn calibration(&self) -> &Calibration {
        &self.cal
    }

    /// The SPI device.
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

    use crate::adc::script::Script;

    #[test]
    fn frames_are_twos_complement_msb_first() {
        for (code, bytes) in [
            (0x12_3456, [0x12, 0x34, 0x56, 0x00]),
            (-1, [0xFF, 0xFF, 0xFF, 0x00]),
            (MIN_CODE, [0x80, 0x00, 0x00, 0x00]),
            (MAX_CODE, [0x7F, 0xFF, 0xFF, 0x00]),
        ] {
            let f = Frame { code, status: 0 };
            assert_eq!(f.encode(), bytes, "{code}");
            assert_eq!(Frame::decode(bytes), f);
        }
        assert_eq!(
            Frame {
                code: i32::MAX,
                status: STATUS_ADC_ERROR
            }
            .encode(),
            [0x7F, 0xFF, 0xFF, 0x40]
        );
        assert!(Frame::decode([0x80, 0, 0, 0]).saturated());
        assert!(!Frame::decode([0x80, 0, 1, 0]).saturated());
    }

    #[test]
    fn calibration_round_trips_within_half_a_count_and_saturates() {
        let cal = Calibration::new(10_000.0, 2150);
        assert_eq!(cal.force_n(2150), 0.0);
        assert_eq!(cal.code_of(0.0), Some(2150));
        for &f in &[1.0f32, -1195.5, 2037.8, 0.0004, -9_000.0] {
            let c = cal.code_of(f).unwrap();
            // Half a count, plus the f32 rounding of the product.
            assert!((cal.force_n(c) - f).abs() <= 0.5 * cal.newtons_per_count + 2e-7 * f.abs());
        }
        assert_eq!(cal.code_of(20_000.0), Some(MAX_CODE));
        assert_eq!(cal.code_of(-20_000.0), Some(MIN_CODE));
        assert_eq!(cal.code_of(f32::NAN), None);
        assert_eq!(cal.code_of(f32::INFINITY), None);
    }

    #[test]
    fn reads_forces_and_refuses_faults_and_saturation() {
        let cal = Calibration::new(10_000.0, -300);
        let ok = |f: f32| {
            Ok(Frame {
                code: cal.code_of(f).unwrap(),
                status: 0,
            }
            .encode())
        };
        let frames = vec![
            ok(1000.0),
            Err(ErrorKind::Overrun),
            Ok(Frame {
                code: 0,
                status: STATUS_NOT_READY,
            }
            .encode()),
            Ok(Frame {
                code: 0,
                status: STATUS_ADC_ERROR,
            }
            .encode()),
            ok(1e6),
            ok(-1e6),
            ok(-250.0),
        ];
        let mut lc = LoadCell::new(
            Script {
                command: READ_DATA_COMMAND,
                frames,
                next: 0,
            },
            cal,
        );
        let f = lc.read_force().unwrap();
        assert!((f - 1000.0).abs() <= cal.newtons_per_count);
        assert_eq!(lc.read_force(), Err(LoadCellError::Bus(ErrorKind::Overrun)));
        assert_eq!(lc.read_force(), Err(LoadCellError::NotReady));
        assert_eq!(lc.read_force(), Err(LoadCellError::Invalid));
        assert_eq!(lc.read_force(), Err(LoadCellError::Saturated));
        assert_eq!(lc.read_force(), Err(LoadCellError::Saturated));
        // No state: the next good sample is read as it is.
        assert!((lc.read_force().unwrap() + 250.0).abs() <= cal.newtons_per_count);
    }
}
