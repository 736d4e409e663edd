//! Replay devices: [`SpiDevice`]s that behave like the firmware's ADCs but serve a recorded
//! bench trace from flash, so that in QEMU the firmware runs the same driver code path a
//! real board runs. [`Replay`] is one converter on a [`ReplayChannel`]: [`ReplayAdc`] the stroke
//! channel's ADC (see [`crate::sensor`]), [`ReplayLoadCell`] the load-cell channel's (see
//! [`crate::loadcell`]); each keeps its own position in the recording, and the firmware reads
//! each once per period.
//!
//! Every read transaction returns the next recorded sample (the converter is triggered by the
//! read, as a SAR ADC with its convert-start tied to chip select), quantised to the ADC's
//! 24-bit code with the channel's calibration. A NaN or out-of-range displacement is served
//! as an invalid conversion (status bit 6), as a real converter reports it; a NaN force too,
//! and a force beyond the load cell's range as the code at the end of the range (the bridge
//! converter saturates without flagging it). After the last sample the devices answer "no
//! new conversion" (status bit 7) and [`Replay::finished`] turns true.
//!
//! Faults can be injected for tests ([`FaultWindow`]): bus errors (the transaction fails, the
//! sample of that period is lost), NaN bursts (the recording's samples are replaced by
//! NaN) and saturation (the samples read full scale). Windows are given in sample indices,
//! e.g. `bus@1200+25`, `nan@3000+40` or `sat@500+10`.

use crate::loadcell;
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
    /// The recorded sample is replaced by NaN (served as an invalid conversion).
    Nan,
    /// The input drives the converter beyond full scale: the stroke ADC flags the
    /// conversion invalid (status bit 6), the load cell's reads the positive end of its
    /// range.
    Saturate,
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
    /// Parses `bus@START+LEN`, `nan@START+LEN` or `sat@START+LEN`.
    pub fn parse(s: &str) -> Option<Self> {
        let (kind, rest) = s.split_once('@')?;
        let kind = match kind {
            "bus" => FaultKind::Bus,
            "nan" => FaultKind::Nan,
            "sat" => FaultKind::Saturate,
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
    /// The transaction is not the ADC's read command (its command byte, then 4 bytes).
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

/// A replayed converter: its read command and what it serves for sample `i` of the trace
/// (`fault(kind)` tells whether an injected fault of `kind` covers the sample).
pub trait ReplayChannel {
    /// The command byte of the converter's read transaction.
    const COMMAND: u8;
    /// The frame bytes of sample `i`, as the converter would send them.
    fn bytes(&self, trace: &Trace<'_>, i: u32, fault: impl Fn(FaultKind) -> bool) -> [u8; 4];
}

/// The stroke channel's ADC, quantised with the calibration its driver uses.
impl ReplayChannel for Calibration {
    const COMMAND: u8 = READ_DATA_COMMAND;

    fn bytes(&self, trace: &Trace<'_>, i: u32, fault: impl Fn(FaultKind) -> bool) -> [u8; 4] {
        let x = match trace.displacement_m(i as usize) {
            None => {
                return Frame {
                    code: 0,
                    status: STATUS_NOT_READY,
                }
                .encode()
            }
            Some(_) if fault(FaultKind::Nan) => f32::NAN,
            Some(_) if fault(FaultKind::Saturate) => f32::INFINITY,
            Some(x) => x,
        };
        match self.code_of(x) {
            Some(code) => Frame { code, status: 0 },
            None => Frame {
                code: if x > 0.0 { crate::sensor::MAX_CODE } else { 0 },
                status: STATUS_ADC_ERROR,
            },
        }
        .encode()
    }
}

/// The load-cell channel's bridge ADC, quantised with the calibration its driver uses.
impl ReplayChannel for loadcell::Calibration {
    const COMMAND: u8 = loadcell::READ_DATA_COMMAND;

    fn bytes(&self, trace: &Trace<'_>, i: u32, fault: impl Fn(FaultKind) -> bool) -> [u8; 4] {
        let invalid = loadcell::Frame {
            code: 0,
            status: loadcell::STATUS_ADC_ERROR,
        };
        let frame = match trace.force_n(i as usize) {
            None => loadcell::Frame {
                code: 0,
                status: loadcell::STATUS_NOT_READY,
            },
            Some(_) if fault(FaultKind::Nan) => invalid,
            Some(_) if fault(FaultKind::Saturate) => loadcell::Frame {
                code: loadcell::MAX_CODE,
                status: 0,
            },
            Some(f) => match self.code_of(f) {
                Some(code) => loadcell::Frame { code, status: 0 },
                None => invalid,
            },
        };
        frame.encode()
    }
}

/// A replaying converter on channel `C`: serves the trace's samples one per read, with the
/// injected faults.
#[derive(Debug)]
pub struct Replay<'a, C> {
    trace: Trace<'a>,
    channel: C,
    next: u32,
    faults: heapless::Vec<FaultWindow, MAX_FAULT_WINDOWS>,
}

/// The replaying stroke ADC.
pub type ReplayAdc<'a> = Replay<'a, Calibration>;

/// The replaying load-cell ADC: serves the recorded force of each sample.
pub type ReplayLoadCell<'a> = Replay<'a, loadcell::Calibration>;

impl<'a, C: ReplayChannel> Replay<'a, C> {
    /// Serves `trace` quantised with `cal` (the calibration the channel's driver uses).
    pub fn new(trace: Trace<'a>, cal: C) -> Self {
        Self {
            trace,
            channel: cal,
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
}

impl<C> ErrorType for Replay<'_, C> {
    type Error = ReplayError;
}

impl<C: ReplayChannel> SpiDevice for Replay<'_, C> {
    fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), ReplayError> {
        let [Operation::Write(cmd), Operation::Read(rx)] = operations else {
            return Err(ReplayError::Protocol);
        };
        if *cmd != [C::COMMAND] || rx.len() != 4 {
            return Err(ReplayError::Protocol);
        }
        let i = self.next;
        if !self.finished() {
            self.next += 1;
        }
        if self.fault_at(i, FaultKind::Bus) {
            return Err(ReplayError::InjectedBusFault);
        }
        rx.copy_from_slice(&self.channel.bytes(&self.trace, i, |k| self.fault_at(i, k)));
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
        assert_eq!(
            FaultWindow::parse("sat@3+4").map(|w| w.kind),
            Some(FaultKind::Saturate)
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

    #[test]
    fn saturation_of_the_stroke_adc_is_an_invalid_conversion() {
        let b = trace_bytes(&[0.0, 0.01, 0.02]);
        let cal = Calibration::new(0.1, 10_000.0);
        let mut adc = ReplayAdc::new(Trace::parse(&b).unwrap(), cal);
        assert!(adc.inject(FaultWindow::parse("sat@1+1").unwrap()));
        let mut s = StrokeSensor::new(adc, cal);
        assert_eq!(s.read_frame().unwrap().status, 0);
        let f = s.read_frame().unwrap();
        assert_eq!(
            (f.code, f.status),
            (crate::sensor::MAX_CODE, STATUS_ADC_ERROR)
        );
        assert_eq!(s.read_frame().unwrap().status, 0);
    }

    #[test]
    fn the_load_cell_reads_the_recorded_force_with_faults() {
        use crate::loadcell::{Calibration as LcCal, LoadCell, LoadCellError};
        let forces = [100.0f32, -2000.5, f32::NAN, 25_000.0, 7.0, 8.0, 9.0, 10.0];
        let samples: Vec<_> = forces.iter().map(|&f| (0.0, f32::NAN, f)).collect();
        let mut b = vec![0; crate::trace::encoded_len(samples.len()).unwrap()];
        crate::trace::encode(10_000.0, 0.15, &samples, &mut b).unwrap();
        let cal = LcCal::new(10_000.0, 2150);
        let mut dev = ReplayLoadCell::new(Trace::parse(&b).unwrap(), cal);
        for w in ["bus@4+1", "nan@5+1", "sat@6+1"] {
            assert!(dev.inject(FaultWindow::parse(w).unwrap()));
        }
        let mut rx = [0u8; 4];
        assert_eq!(
            dev.transaction(&mut [
                Operation::Write(&[READ_DATA_COMMAND]),
                Operation::Read(&mut rx)
            ]),
            Err(ReplayError::Protocol),
            "the stroke ADC's command"
        );
        let mut lc = LoadCell::new(dev, cal);
        let mut got = Vec::new();
        while !lc.spi().finished() {
            got.push(lc.read_force());
        }
        assert_eq!(got.len(), forces.len());
        let step = cal.newtons_per_count;
        assert!((got[0].unwrap() - 100.0).abs() <= step);
        assert!((got[1].unwrap() + 2000.5).abs() <= step);
        assert_eq!(got[2], Err(LoadCellError::Invalid), "NaN recorded");
        assert_eq!(got[3], Err(LoadCellError::Saturated), "beyond full scale");
        assert_eq!(
            got[4],
            Err(LoadCellError::Bus(ReplayError::InjectedBusFault))
        );
        assert_eq!(got[5], Err(LoadCellError::Invalid));
        assert_eq!(got[6], Err(LoadCellError::Saturated));
        assert!((got[7].unwrap() - 10.0).abs() <= step);
        assert_eq!(
            lc.read_force(),
            Err(LoadCellError::NotReady),
            "past the end"
        );
    }
}
