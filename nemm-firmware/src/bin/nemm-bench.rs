//! Instructions per estimator step on the target (`cargo xtask bench-target`).
//!
//! Loads the weights slot like the application, turns the first samples of the recorded trace
//! into velocities through the real sensor path, then, for each integrator, times
//! `Estimator::step` over them with SysTick (core clock, free running) and prints
//!
//! ```text
//! bench kind=nemm integrator=rk4 mode=exact steps=2000 ticks=812345 baseline_ticks=2001
//! ```
//!
//! Every step is timed on its own (the 24-bit counter wraps after 2^24 ticks); `ticks` is the
//! sum, `baseline_ticks` the same measurement around an empty body. Under `qemu-system-arm -icount shift=0`
//! one instruction takes 1 ns and one SysTick tick 40 ns, so the host turns
//! `(ticks - baseline_ticks) * 40 / steps` into instructions per step.
//!
//! Options (QEMU command line): `mode=exact` (the only mode so far), `steps=N` (1..=4000).
#![no_std]
#![no_main]
#![deny(missing_docs)]
#![deny(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::unreachable,
    clippy::todo
)]

use core::hint::black_box;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::entry;
use nemm_core::{decode, Estimator, EstimatorConfig, Integrator, Model};
use nemm_firmware::board::{self, Console};
use nemm_firmware::report::{self, Line};
use nemm_firmware::trace::Trace;
use nemm_firmware::{slot, StaticSlot, PARAM_CAPACITY};

/// Most steps per measurement.
const MAX_STEPS: usize = 4000;
/// Steps run before measuring (state and caches settle into the trace's regime).
const WARMUP_STEPS: usize = 200;
/// SysTick reload: the full 24-bit range.
const SYST_RANGE: u32 = 1 << 24;

/// Evaluation modes of the scalers; only the exact one exists so far.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Exact,
}

impl Mode {
    fn parse(s: &str) -> Option<Self> {
        match s {
            "exact" => Some(Mode::Exact),
            _ => None,
        }
    }
    fn name(self) -> &'static str {
        match self {
            Mode::Exact => "exact",
        }
    }
}

fn fail(console: &mut Console, line: &mut Line, code: u32) -> ! {
    console.write(line.finish());
    board::exit(code)
}

fn ticks_since(start: u32) -> u32 {
    start.wrapping_sub(SYST::get_current()) & (SYST_RANGE - 1)
}

static MODEL: StaticSlot<Model<PARAM_CAPACITY>> = StaticSlot::new();
static ESTIMATOR: StaticSlot<Option<Estimator<PARAM_CAPACITY>>> = StaticSlot::new();
static VELOCITIES: StaticSlot<[f32; MAX_STEPS + WARMUP_STEPS]> = StaticSlot::new();

/// Iterations of the calibration loops.
const CALIBRATION_ITERATIONS: u32 = 1_000_000;

/// Times loops of known instruction counts (integer: `subs; bne`, 2 per iteration; FPU:
/// `vadd.f32; subs; bne`, 3 per iteration) and prints their ticks, so the host can check the
/// instructions-per-tick factor it assumes.
fn calibrate(console: &mut Console) {
    let start = SYST::get_current();
    // SAFETY: a register-only countdown loop.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {n}, #1",
            "bne 2b",
            n = inout(reg) CALIBRATION_ITERATIONS => _,
            options(nomem, nostack),
        );
    }
    let int_ticks = ticks_since(start);
    let start = SYST::get_current();
    // SAFETY: `s0`/`s1` are saved in core registers and restored; no memory access.
    unsafe {
        core::arch::asm!(
            "vmov {t0}, {t1}, s0, s1",
            "2:",
            "vadd.f32 s0, s0, s1",
            "subs {n}, #1",
            "bne 2b",
            "vmov s0, s1, {t0}, {t1}",
            n = inout(reg) CALIBRATION_ITERATIONS => _,
            t0 = out(reg) _,
            t1 = out(reg) _,
            options(nomem, nostack),
        );
    }
    let fp_ticks = ticks_since(start);
    let mut l = Line::new();
    l.str("calibration")
        .kv("iterations", CALIBRATION_ITERATIONS)
        .kv("int_loop_ticks", int_ticks)
        .kv("fp_loop_ticks", fp_ticks);
    console.write(l.finish());
}

#[entry]
fn main() -> ! {
    let mut console = Console::open();
    let mut mode = Mode::Exact;
    let mut steps = 2000usize;
    let mut args = [0u8; board::ARGS_CAPACITY];
    for arg in board::args(&mut args)
        .unwrap_or("")
        .split_ascii_whitespace()
    {
        let ok = if let Some(m) = arg.strip_prefix("mode=") {
            Mode::parse(m).map(|m| mode = m).is_some()
        } else if let Some(n) = arg.strip_prefix("steps=") {
            match n.parse::<usize>() {
                Ok(n) if (1..=MAX_STEPS).contains(&n) => {
                    steps = n;
                    true
                }
                _ => false,
            }
        } else {
            !arg.contains('=') // the program name
        };
        if !ok {
            let mut l = Line::new();
            l.str("error").ks("kind", "bad-option").ks("option", arg);
            fail(&mut console, &mut l, report::EXIT_USAGE)
        }
    }

    let model = match slot::blob(board::weights_slot()) {
        Err(e) => {
            let mut l = Line::new();
            report::slot_error(&mut l, &e);
            fail(&mut console, &mut l, report::EXIT_BAD_WEIGHTS)
        }
        Ok(blob) => match decode(blob) {
            Ok(m) => match MODEL.init(m) {
                Some(m) => &*m,
                None => board::exit(report::EXIT_USAGE),
            },
            Err(e) => {
                let mut l = Line::new();
                report::decode_error(&mut l, &e);
                fail(&mut console, &mut l, report::EXIT_BAD_WEIGHTS)
            }
        },
    };
    let Ok(trace) = Trace::parse(board::trace_bytes()) else {
        let mut l = Line::new();
        l.str("error").ks("kind", "trace");
        fail(&mut console, &mut l, report::EXIT_USAGE)
    };

    // Velocities through the real sensor path (a sample without one holds the previous).
    let Some(velocities) = VELOCITIES.init([0.0; MAX_STEPS + WARMUP_STEPS]) else {
        board::exit(report::EXIT_USAGE)
    };
    let mut sensor = board::sensor(trace);
    let mut last = 0.0f32;
    for v in velocities.iter_mut() {
        if let Ok(x) = sensor.read_velocity() {
            last = x;
        }
        *v = last;
    }
    let velocities = velocities.get(..steps + WARMUP_STEPS).unwrap_or(&[]);
    let (warmup, measured) = velocities.split_at(WARMUP_STEPS.min(velocities.len()));

    // SAFETY: this program is the only user of SysTick.
    let mut syst = unsafe { cortex_m::Peripherals::steal() }.SYST;
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(SYST_RANGE - 1);
    syst.clear_current();
    syst.enable_counter();

    calibrate(&mut console);

    let Some(est_slot) = ESTIMATOR.init(None) else {
        board::exit(report::EXIT_USAGE)
    };
    for integrator in [Integrator::Rk4, Integrator::Rk3] {
        let cfg = EstimatorConfig {
            integrator: Some(integrator),
            ..EstimatorConfig::new(trace.oil_loss)
        };
        let est = match Estimator::new(model, cfg) {
            Ok(e) => est_slot.insert(e),
            Err(e) => {
                let mut l = Line::new();
                report::estimator_error(&mut l, &e);
                fail(&mut console, &mut l, report::EXIT_BAD_WEIGHTS)
            }
        };
        for &v in warmup {
            black_box(est.step(black_box(v)));
        }

        // Each step is timed on its own: the 24-bit counter wraps after 16.7 M ticks
        // (671 M instructions), far less than a whole run of slow steps.
        let mut baseline = 0u32;
        for &v in measured {
            let start = SYST::get_current();
            black_box(black_box(v));
            baseline = baseline.wrapping_add(ticks_since(start));
        }
        let mut ticks = 0u32;
        for &v in measured {
            let start = SYST::get_current();
            black_box(est.step(black_box(v)));
            ticks = ticks.wrapping_add(ticks_since(start));
        }

        let mut l = Line::new();
        l.str("bench")
            .ks("kind", model.kind().name())
            .ks("integrator", integrator.name())
            .ks("mode", mode.name())
            .kv("steps", measured.len() as u32)
            .kv("ticks", ticks)
            .kv("baseline_ticks", baseline)
            .kv("held", est.diagnostics().held_samples)
            .kv("resets", est.diagnostics().resets);
        console.write(l.finish());
    }
    board::exit(report::EXIT_DONE)
}
