//! A replay device: an [`SpiDevice`] that behaves like the stroke channel's ADC (see
//! [`crate::sensor`]) but serves a recorded bench trace from flash, so that in QEMU the
//! firmware runs the same driver code path a real board runs.
//!
//! Every read transaction returns the next recorded sample (the converter is triggered by the
//! read, as a SAR ADC with its convert-start tied to chip select), quantised to the ADC's
//! 24-bit code with the channel's calibration. A NaN or out-of-range displacement is served
//! as an invalid conversion (status bit 6), as a real converter reports it. After the last
//! sample the device answers "no new conversion" (status bit 7) and [`ReplayAdc::finished`]
//! turns true.
//!
//! Faults can be injected for tests ([`FaultWindow`]): bus errors (the transaction fails, the
//! sample of that period is lost) and NaN bursts (the recording's samples are replaced by
//! NaN). Windows are given in sample indices, e.g. `bus@1200+25` or `nan@3000+40`.

use crate::sensor::{Calibration, Frame, READ_DATA_COMMAND, STATUS_ADC_ERROR, STATUS_NOT_READY};
use crate::trace::Trace;
use embedded_hal::spi::{self, ErrorKind, ErrorType, Operation, SpiDevice};

/// Most fault windows one run can inject.
pub const MAX_FAULT_WINDOWS: usize = 8;

/// What an injected fault does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// The SPI transaction fails.
    Bus,
    /// The recorded displacement is replaced by NaN (served as an invalid conversion).
    Nan,
}

/// Samples `start .. start + len` are affected by `kind`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultWindow {
    /// What happens.
    pub kind: FaultKind,
    /// First sample index.
    pub start: u32,
    /// Number of samples.
    pub len: u32,
}

impl FaultWindow {
    /// Parses `bus@START+LEN` or `nan@START+LEN`.
    pub fn parse(s: &str) -> Option<Self> {
        let (kind, rest) = s.split_once('@')?;
        let kind = match kind {
            "bus" => FaultKind::Bus,
            "nan" => FaultKind::Nan,
            _ => return None,
        };
        let (start, len) = rest.split_once('+')?;
        Some(Self {
            kind,
            start: start.parse().ok()?,
            len: len.parse().ok()?,
        })
    }

    fn covers(&self, i: u32) -> bool {
        i >= self.start && i - self.start < self.len
    }
}

/// Errors of the replay device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplayError {
    /// An injected bus fault.
    InjectedBusFault,
    /// The transaction is not the ADC's read command (`0x44`, then 4 bytes).
    Protocol,
}

impl spi::Error for ReplayError {
    fn kind(&self) -> ErrorKind {
        match self {
            ReplayError::InjectedBusFault => ErrorKind::Other,
            ReplayError::Protocol => ErrorKind::FrameFormat,
        }
    }
}

/// The replaying ADC.
#[derive(Debug)]
pub struct ReplayAdc<'a> {
    trace: Trace<'a>,
    cal: Calibration,
    next: u32,
    faults: heapless::Vec<FaultWindow, MAX_FAULT_WINDOWS>,
}

impl<'a> ReplayAdc<'a> {
    /// Serves `trace` quantised with `cal` (the calibration the driver uses).
    pub fn new(trace: Trace<'a>, cal: Calibration) -> Self {
        Self {
            trace,
            cal,
            next: 0,
            faults: heapless::Vec::new(),
        }
    }

    /// Adds a fault window; `false` if [`MAX_FAULT_WINDOWS`] are already set.
    pub fn inject(&mut self, w: FaultWindow) -> bool {
        self.faults.push(w).is_ok()
    }

    /// Index of the next sample to serve.
    pub fn position(&self) -> u32 {
        self.next
    }

    /// True once every recorded sample was served.
    pub fn finished(&self) -> bool {
        self.next as usize >= self.trace.len()
    }

    /// The trace being served.
    pub fn trace(&self) -> &Trace<'a> {
        &self.trace
    }

    fn fault_at(&self, i: u32, kind: FaultKind) -> bool {
        self.faults.iter().any(|w| w.kind == kind && w.covers(i))
    }

    /// The frame of sample `i` as the ADC would send it.
    fn frame(&self, i: u32) -> Frame {
        let x = match self.trace.displacement_m(i as usize) {
            None => {
                return Frame {
                    code: 0,
                    status: STATUS_NOT_READY,
                }
            }
            Some(_) if self.fault_at(i, FaultKind::Nan) => f32::NAN,
            Some(x) => x,
        };
        match self.cal.code_of(x) {
            Some(code) => Frame { code, status: 0 },
            None => Frame {
                code: if x > 0.0 { crate::sensor::MAX_CODE } else { 0 },
                status: STATUS_ADC_ERROR,
            },
        }
    }
}

impl ErrorType for ReplayAdc<'_> {
    type Error = ReplayError;
}

impl SpiDevice for ReplayAdc<'_> {
    fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), ReplayError> {
        let [Operation::Write(cmd), Operation::Read(rx)] = operations else {
            return Err(ReplayError::Protocol);
        };
        if *cmd != [READ_DATA_COMMAND] || rx.len() != 4 {
            return Err(ReplayError::Protocol);
        }
        let i = self.next;
        if !self.finished() {
            self.next += 1;
        }
        if self.fault_at(i, FaultKind::Bus) {
            return Err(ReplayError::InjectedBusFault);
        }
        rx.copy_from_slice(&self.frame(i).encode());
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensor::{SensorError, StrokeSensor};
    use std::vec::Vec;

    fn trace_bytes(xs: &[f32]) -> Vec<u8> {
        let samples: Vec<_> = xs.iter().map(|&x| (x, f32::NAN, f32::NAN)).collect();
        let mut b = vec![0; crate::trace::encoded_len(xs.len()).unwrap()];
        crate::trace::encode(10_000.0, 0.0, &samples, &mut b).unwrap();
        b
    }

    #[test]
    fn parses_fault_windows() {
        assert_eq!(
            FaultWindow::parse("bus@1200+25"),
            Some(FaultWindow {
                kind: FaultKind::Bus,
                start: 1200,
                len: 25
            })
        );
        assert_eq!(
            FaultWindow::parse("nan@7+1").map(|w| w.kind),
            Some(FaultKind::Nan)
        );
        for bad in ["bus1200+25", "dust@1+1", "nan@x+1", "nan@1", "nan@1+-2"] {
            assert_eq!(FaultWindow::parse(bad), None, "{bad}");
        }
    }

    #[test]
    fn driver_reads_the_trace_through_the_replay_device() {
        // 0.2 m/s ramp (20 um per sample), a NaN in the recording, an injected bus fault.
        let mut xs: Vec<f32> = (0..12).map(|n| n as f32 * 20e-6).collect();
        xs[5] = f32::NAN;
        let b = trace_bytes(&xs);
        let cal = Calibration::new(0.1, 10_000.0);
        let mut adc = ReplayAdc::new(Trace::parse(&b).unwrap(), cal);
        assert!(adc.inject(FaultWindow::parse("bus@9+1").unwrap()));
        let mut s = StrokeSensor::new(adc, cal);
        let mut got = Vec::new();
        while !s.spi().finished() {
            got.push(s.read_velocity());
        }
        assert_eq!(got.len(), 12);
        assert_eq!(got[0], Err(SensorError::Priming));
        for v in &got[1..5] {
            assert!((v.unwrap() - 0.2).abs() < 1e-3, "{v:?}");
        }
        assert_eq!(got[5], Err(SensorError::Invalid));
        assert_eq!(got[6], Err(SensorError::Priming));
        assert!((got[7].unwrap() - 0.2).abs() < 1e-3);
        assert_eq!(got[9], Err(SensorError::Bus(ReplayError::InjectedBusFault)));
        assert_eq!(got[10], Err(SensorError::Priming));
        // Past the end: no new conversion.
        assert_eq!(s.read_velocity(), Err(SensorError::NotReady));
    }

    #[test]
    fn out_of_range_is_an_invalid_conversion_and_bad_commands_are_refused() {
        let b = trace_bytes(&[0.5, -0.5]);
        let cal = Calibration::new(0.1, 10_000.0);
        let mut adc = ReplayAdc::new(Trace::parse(&b).unwrap(), cal);
        let mut rx = [0u8; 4];
        assert_eq!(
            adc.transaction(&mut [Operation::Write(&[0x10]), Operation::Read(&mut rx)]),
            Err(ReplayError::Protocol)
        );
        let mut s = StrokeSensor::new(adc, cal);
        let f = s.read_frame().unwrap();
        assert_eq!(
            (f.code, f.status),
            (crate::sensor::MAX_CODE, STATUS_ADC_ERROR)
        );
        let f = s.read_frame().unwrap();
        assert_eq!((f.code, f.status), (0, STATUS_ADC_ERROR));
    }
}
