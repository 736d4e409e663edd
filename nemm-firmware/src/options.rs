//! Run options of the QEMU build (`qemu` feature), read from the semihosting command line
//! (`qemu-system-arm ... -semihosting-config enable=on,arg=fw,arg=OPTION,...`). A board build
//! has no command line and runs with the defaults.
//!
//! | option | effect |
//! |--------|--------|
//! | `mode=exact\|table` | evaluation of the neural coefficients (default: exact, or table with the `table` feature; see [`crate::eval_mode`]) |
//! | `fault=bus@START+LEN` | the SPI transaction of samples `START .. START+LEN` fails ([`crate::replay`]) |
//! | `fault=nan@START+LEN` | the recorded displacement of those samples is NaN (an invalid conversion) |
//! | `fault=sat@START+LEN` | the stroke ADC reads over-range for those samples (an invalid conversion) |
//! | `observer=on\|off` | the bench-controller mode: read the load cell and run the alpha observer beside the estimator (default: off, or on with the `observer` feature; see [`crate::OBSERVER_DEFAULT`]) |
//! | `lcfault=bus\|nan\|sat@START+LEN` | the load cell's SPI transaction fails, its conversion is invalid, or it reads full scale (saturated) for those samples (with the observer) |
//! | `period_ticks=N` | sample period in SysTick ticks (default: 10 kHz); a slower sample clock for tests |
//! | `samples=N` | replay only the first `N` samples of the recording |
//! | `stall=START+LEN` | in the periods of samples `START .. START+LEN` the task busy-waits one whole period before its step: a deterministic overrun |
//!
//! Words without `=` (the program name) are ignored; anything else is refused.

use crate::replay::{FaultWindow, MAX_FAULT_WINDOWS};

/// Shortest accepted `period_ticks` (100 ticks: 4,000 instructions at QEMU's 25 MHz SysTick).
pub const MIN_PERIOD_TICKS: u32 = 100;
/// Longest accepted `period_ticks` (SysTick's reload register has 24 bits).
pub const MAX_PERIOD_TICKS: u32 = 0xFF_FFFF;
/// Most `stall=` windows.
pub const MAX_STALL_WINDOWS: usize = 4;

/// Samples `start .. start + len`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// First sample index.
    pub start: u32,
    /// Number of samples.
    pub len: u32,
}

impl Window {
    /// Parses `START+LEN`.
    pub fn parse(s: &str) -> Option<Self> {
        let (start, len) = s.split_once('+')?;
        Some(Self {
            start: start.parse().ok()?,
            len: len.parse().ok()?,
        })
    }

    /// True if sample `i` lies in the window.
    pub fn covers(&self, i: u32) -> bool {
        i >= self.start && i - self.start < self.len
    }
}

/// The options of one run.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Options {
    /// Injected sensor faults.
    pub faults: heapless::Vec<FaultWindow, MAX_FAULT_WINDOWS>,
    /// Sample period in SysTick ticks (`None`: the board's 10 kHz period).
    pub period_ticks: Option<u32>,
    /// Replay only this many samples (`None`: the whole recording).
    pub samples: Option<u32>,
    /// Periods that overrun on purpose.
    pub stalls: heapless::Vec<Window, MAX_STALL_WINDOWS>,
    /// `mode=table` (`Some(true)`) or `mode=exact` (`Some(false)`); `None`: the build's
    /// default ([`crate::TABLE_MODE_DEFAULT`]).
    pub table: Option<bool>,
    /// `observer=on` (`Some(true)`) or `observer=off` (`Some(false)`); `None`: the build's
    /// default ([`crate::OBSERVER_DEFAULT`]).
    pub observer: Option<bool>,
    /// Injected load-cell faults.
    pub load_cell_faults: heapless::Vec<FaultWindow, MAX_FAULT_WINDOWS>,
}

impl Options {
    /// Parses a whitespace-separated command line; `Err` carries the refused word.
    pub fn parse(cmdline: &str) -> Result<Self, &str> {
        let mut o = Options::default();
        for arg in cmdline.split_ascii_whitespace() {
            let ok = if let Some(w) = arg.strip_prefix("fault=") {
                FaultWindow::parse(w).is_some_and(|w| o.faults.push(w).is_ok())
            } else if let Some(n) = arg.strip_prefix("period_ticks=") {
                match n.parse::<u32>() {
                    Ok(n) if (MIN_PERIOD_TICKS..=MAX_PERIOD_TICKS).contains(&n) => {
                        o.period_ticks = Some(n);
                        true
                    }
                    _ => false,
                }
            } else if let Some(n) = arg.strip_prefix("samples=") {
                n.parse::<u32>().map(|n| o.samples = Some(n)).is_ok()
            } else if let Some(m) = arg.strip_prefix("mode=") {
                match m {
                    "exact" => o.table = Some(false),
                    "table" => o.table = Some(true),
                    _ => return Err(arg),
                }
                true
            } else if let Some(m) = arg.strip_prefix("observer=") {
                match m {
                    "on" => o.observer = Some(true),
                    "off" => o.observer = Some(false),
                    _ => return Err(arg),
                }
                true
            } else if let Some(w) = arg.strip_prefix("lcfault=") {
                FaultWindow::parse(w).is_some_and(|w| o.load_cell_faults.push(w).is_ok())
            } else if let Some(w) = arg.strip_prefix("stall=") {
                Window::parse(w).is_some_and(|w| o.stalls.push(w).is_ok())
            } else {
                !arg.contains('=')
            };
            if !ok {
                return Err(arg);
            }
        }
        Ok(o)
    }

    /// Whether the observer runs: `observer=`, else the build's default.
    pub fn observer_on(&self) -> bool {
        self.observer.unwrap_or(crate::OBSERVER_DEFAULT)
    }

    /// True if the period of sample `i` is to overrun on purpose.
    pub fn stalls_at(&self, i: u32) -> bool {
        self.stalls.iter().any(|w| w.covers(i))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::FaultKind;

    #[test]
    fn parses_every_option_and_refuses_the_rest() {
        let o = Options::parse(
            "fw fault=bus@10+2 fault=nan@20+3 period_ticks=5000 samples=300 stall=7+1",
        )
        .unwrap();
        assert_eq!(o.faults.len(), 2);
        assert_eq!(o.faults[1].kind, FaultKind::Nan);
        assert_eq!(o.period_ticks, Some(5000));
        assert_eq!(o.samples, Some(300));
        assert!(o.stalls_at(7) && !o.stalls_at(8) && !o.stalls_at(6));
        assert_eq!(o.table, None);
        assert_eq!(Options::parse("fw mode=table").unwrap().table, Some(true));
        assert_eq!(Options::parse("fw mode=exact").unwrap().table, Some(false));
        assert_eq!(Options::parse("").unwrap(), Options::default());
        let o = Options::parse("fw observer=on lcfault=sat@5+2 lcfault=bus@9+1").unwrap();
        assert_eq!(o.observer, Some(true));
        assert!(o.observer_on());
        assert_eq!(o.load_cell_faults.len(), 2);
        assert_eq!(o.load_cell_faults[0].kind, FaultKind::Saturate);
        assert!(o.faults.is_empty());
        assert_eq!(
            Options::parse("fw observer=off").unwrap().observer,
            Some(false)
        );
        assert_eq!(
            Options::parse("fw").unwrap().observer_on(),
            crate::OBSERVER_DEFAULT
        );
        for bad in [
            "period_ticks=99",
            "period_ticks=16777216",
            "samples=-1",
            "stall=3",
            "fault=dust@1+1",
            "verbose=1",
            "mode=fast",
            "observer=1",
            "lcfault=dust@1+1",
        ] {
            assert_eq!(Options::parse(&format!("fw {bad}")), Err(bad), "{bad}");
        }
        let nine = "fault=bus@1+1 ".repeat(MAX_FAULT_WINDOWS + 1);
        assert_eq!(Options::parse(&nine), Err("fault=bus@1+1"));
    }
}
