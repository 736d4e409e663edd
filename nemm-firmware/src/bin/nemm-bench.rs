//! Instructions per estimator step on the target (`cargo xtask bench-target`), the on-target
//! check of the scalers' FPU kernels, and force bits for the host/target parity check.
//!
//! The model is the weights slot's (as in the application), or with `example=<kind>` the
//! example model `nemm_core::testing::example_model(kind, hidden, layers)` built on the
//! target (no rebuild per kind). The input is the first samples of the recorded trace turned
//! into velocities through the real sensor path. For each integrator it times
//! `Estimator::step` with SysTick (core clock, free running) and prints one line:
//!
//! ```text
//! bench kind=nemm integrator=rk4 mode=exact hidden=16 layers=5 steps=2000 ticks=775432 baseline_ticks=250 instructions_per_step=15504 held=0 resets=0
//! ```
//!
//! Every step is timed on its own (the 24-bit counter wraps after 2^24 ticks); `ticks` is the
//! sum, `baseline_ticks` the same measurement around an empty body. Under `qemu-system-arm
//! -icount shift=0` one instruction takes 1 ns and one SysTick tick 40 ns (the `calibration`
//! line checks it: 2 instructions per iteration of `int_loop`), and `instructions_per_step =
//! round((ticks - baseline_ticks) * 2 * iterations / (int_loop_ticks * steps))`. On real
//! hardware the same formula gives cycles per step times 2 / (cycles of one `subs; bne`
//! iteration); read `ticks` there instead. `hidden`/`layers` are those of the neural scalers
//! (`0` for the SEM and the linear EMM).
//!
//! Options (QEMU command line, `-semihosting-config ...,arg=nemm-bench,arg=steps=500`):
//!
//! - `mode=exact|table` (default exact): the compiled MLPs, or the tabulated fast path
//!   (`nemm_core::EvalMode::Table`, [`nemm_firmware::TABLE_SEGMENTS`] segments per table,
//!   bound [`nemm_firmware::TABLE_MAX_REL_ERROR`]); each `bench` line is followed by
//!   `table kind=.. integrator=.. segments=<T> tables=<n> table_bytes=<B>
//!   max_rel_error_ppb=<e> kinks=<k> build_ticks=<t>` (the tables' bytes, the measured worst
//!   relative error in parts per billion, the kinks made knots in the worst table, and the
//!   SysTick ticks of building the estimator, tables and their check included; wraps of
//!   the 24-bit counter are counted by the SysTick exception), `steps=N` (1..=4000, default 2000),
//!   `warmup=N` (0..=200, default 200), `integrator=rk4|rk3|both` (default both).
//! - `example=sem|linear-emm|nemm-light|nemm`, `hidden=H` (default 16), `layers=L`
//!   (default 5): the example model instead of the weights slot (`H`, `L` must fit the
//!   firmware's parameter capacity, e.g. `H = 8` up to `L = 9`, `H = 32` up to `L = 2`).
//! - `check=N`: before the benchmark, compares for every neural scaler of the model the raw
//!   output of the FPU kernel with the portable code at `N` inputs across `±1.5` training
//!   scales plus special values, bit for bit:
//!   `kernel-check scaler=b_fl hidden=16 layers=5 inputs=N mismatches=0`
//!   (exit code 1 if any differ).
//! - `parity=N`: instead of timing, runs `N` steps (1..=4000) per integrator from a fresh
//!   estimator (no warm-up) and prints every step as
//!   `p <k> <velocity bits> <force bits> <flags>` (hex, `f32::to_bits`),
//!   framed by `parity kind=... integrator=... steps=N` and
//!   `parity-end integrator=... steps=N fnv=<FNV-1a of the force bits>`: the host runs the
//!   same velocities through `nemm-core` and compares the bits.
//! - `lost-motion=1`: the model (weights slot or example) gets
//!   `nemm_core::testing::EXAMPLE_LOST_MOTION`, the example lost-motion element, before the
//!   estimator is built (refused on the SEM: `error kind=lost-motion-on-sem`). The lines of a
//!   model with the element (this option, or a blob with one) name the kind `<kind>+lm`,
//!   e.g. `bench kind=nemm+lm ...`.
//! - `calibrate=0` skips the calibration loops.
//! - `observer=1`: instead of the estimator, times one step of the firmware's alpha observer
//!   ([`nemm_firmware::FwObserver`], its settings [`nemm_firmware::observer_config`]: a bank of
//!   exact-mode model steps, one per level, whatever `mode=`) per sample, on the velocities
//!   and the model's own force at the trace's alpha (an exact-mode estimator's, computed
//!   before): after `warmup=` steps (the observer's own 10 ms warm-up is 100), `steps=`
//!   steps timed each on its own through `observer_step` (not inlined: the cycle model's
//!   trace stops there), one line:
//!   `observer kind=nemm integrator=rk4 levels=7 model_steps=7 bytes=<B> steps=N
//!   ticks=<t> baseline_ticks=<b> instructions_per_step=<n> held=<h>` (`held`: measured steps
//!   that did not update the estimate; `integrator`: the model's; `bytes`: the observer's
//!   RAM, its level tables (in their own static) included when it steps on them), then
//!   `observer-steps closes=<c> max_step_ticks=<m> max_step_instructions=<i>
//!   close_step_ticks=<t> close_step_instructions=<j>`: `closes` the measured steps that
//!   closed a block of stroke cycles, `max_step_*` the longest measured step, `close_step_*`
//!   the first close of a block (the heaviest step: the window's sums and fits), met by
//!   stepping on over the trace again if none was measured (`close_step=none` if none in
//!   20 passes); instructions less the mean baseline of one timing.
#![no_std]
#![no_main]

use core::hint::black_box;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::{entry, exception};
use nemm_core::{
    decode_into, AlphaEstimate, Body, Estimate, EstimatorConfig, EvalMode, Flags, Integrator,
    Model, ModelKind, ObserverFlags, Sample, StoredTables,
};
use nemm_firmware::board::{self, Console};
use nemm_firmware::report::{self, Line};
use nemm_firmware::trace::Trace;
use nemm_firmware::{slot, FwObserver, StaticSlot, PARAM_CAPACITY};
use nemm_kernels::mlp::{CompiledScaler, Scaler};

/// Most steps per measurement.
const MAX_STEPS: usize = 4000;
/// Most steps run before measuring (state settles into the trace's regime).
const MAX_WARMUP_STEPS: usize = 200;
/// SysTick reload: the full 24-bit range.
const SYST_RANGE: u32 = 1 << 24;
/// Exit code of a kernel-check mismatch.
const EXIT_CHECK_FAILED: u32 = 1;
/// What the lines' `kind=` appends to the model kind when the model has a lost-motion
/// element (`lost-motion=1`, or a blob with one): `nemm+lm`. `cargo xtask bench-target`
/// names these runs the same (its `Variant`).
const LOST_MOTION_SUFFIX: &str = "+lm";

/// Evaluation modes of the scalers: the compiled MLPs, or the verified tables of
/// `nemm_kernels::table` (256 segments, bound 1e-4 relative per coefficient).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Exact,
    Table,
}

impl Mode {
    fn parse(s: &str) -> Option<Self> {
        match s {
            "exact" => Some(Mode::Exact),
            "table" => Some(Mode::Table),
            _ => None,
        }
    }
    fn name(self) -> &'static str {
        match self {
            Mode::Exact => "exact",
            Mode::Table => "table",
        }
    }
    fn eval_mode(self) -> EvalMode {
        nemm_firmware::eval_mode(self == Mode::Table)
    }
}

fn parse_kind(s: &str) -> Option<ModelKind> {
    s.parse().ok()
}

/// Command-line options.
struct Options {
    mode: Mode,
    steps: usize,
    warmup: usize,
    integrators: &'static [Integrator],
    example: Option<ModelKind>,
    hidden: u8,
    layers: u8,
    check: u32,
    parity: usize,
    calibrate: bool,
    observer: bool,
    lost_motion: bool,
}

impl Options {
    /// Applies one `key=value` argument; `false` if it is not a valid option.
    fn apply(&mut self, arg: &str) -> bool {
        let Some((k, v)) = arg.split_once('=') else {
            return true; // the program name
        };
        let num = |lo: usize, hi: usize| v.parse::<usize>().ok().filter(|n| (lo..=hi).contains(n));
        // A switch: `0` or `1`.
        let flag = match v {
            "0" => Some(false),
            "1" => Some(true),
            _ => None,
        };
        match k {
            "mode" => Mode::parse(v).map(|m| self.mode = m).is_some(),
            "steps" => num(1, MAX_STEPS).map(|n| self.steps = n).is_some(),
            "warmup" => num(0, MAX_WARMUP_STEPS).map(|n| self.warmup = n).is_some(),
            "integrator" => {
                self.integrators = match v {
                    "rk4" => &[Integrator::Rk4],
                    "rk3" => &[Integrator::Rk3],
                    "both" => &[Integrator::Rk4, Integrator::Rk3],
                    _ => return false,
                };
                true
            }
            "example" => parse_kind(v).map(|kd| self.example = Some(kd)).is_some(),
            "hidden" => num(1, 32).map(|n| self.hidden = n as u8).is_some(),
            "layers" => num(1, 9).map(|n| self.layers = n as u8).is_some(),
            "check" => num(0, 1_000_000).map(|n| self.check = n as u32).is_some(),
            "parity" => num(1, MAX_STEPS).map(|n| self.parity = n).is_some(),
            "observer" => flag.map(|b| self.observer = b).is_some(),
            "lost-motion" => flag.map(|b| self.lost_motion = b).is_some(),
            "calibrate" => flag.map(|b| self.calibrate = b).is_some(),
            _ => false,
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

/// SysTick wraps counted while [`long_ticks`] measures (the interrupt is enabled only there,
/// so that the per-step measurements see no exception).
static SYST_WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    SYST_WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// SysTick ticks of `f`, however long it takes (wraps of the 24-bit counter are counted by
/// the SysTick exception; saturating at `u32::MAX`, 171 G instructions).
fn long_ticks<R>(syst: &mut SYST, f: impl FnOnce() -> R) -> (R, u32) {
    SYST_WRAPS.store(0, Ordering::Relaxed);
    syst.clear_current();
    let start = SYST::get_current();
    syst.enable_interrupt();
    let r = f();
    syst.disable_interrupt();
    let end = SYST::get_current();
    let wraps = u64::from(SYST_WRAPS.load(Ordering::Relaxed));
    // The counter counts down from `start`; each wrap adds the full range.
    let ticks =
        wraps * u64::from(SYST_RANGE) + u64::from(start.wrapping_sub(end) & (SYST_RANGE - 1));
    (r, u32::try_from(ticks).unwrap_or(u32::MAX))
}

static MODEL: StaticSlot<Model<PARAM_CAPACITY>> = StaticSlot::new();
static ESTIMATOR: StaticSlot<Option<nemm_firmware::FwEstimator>> = StaticSlot::new();
static VELOCITIES: StaticSlot<[f32; MAX_STEPS + MAX_WARMUP_STEPS]> = StaticSlot::new();
static COMPILED: StaticSlot<Option<CompiledScaler<PARAM_CAPACITY>>> = StaticSlot::new();
static OBSERVER: StaticSlot<FwObserver> = StaticSlot::new();
/// The level tables of the observer (read from the blob).
static LEVELS: StaticSlot<nemm_firmware::FwLevels> = StaticSlot::new();
static FORCES: StaticSlot<[f32; MAX_STEPS + MAX_WARMUP_STEPS]> = StaticSlot::new();

/// Iterations of the calibration loops.
const CALIBRATION_ITERATIONS: u32 = 1_000_000;

/// Times loops of known instruction counts (integer: `subs; bne`, 2 per iteration; FPU:
/// `vadd.f32; subs; bne`, 3 per iteration), prints their ticks, and returns the integer
/// loop's ticks (the instructions-per-tick factor is `2 * iterations / ticks`).
fn calibrate(console: &mut Console) -> u32 {
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
    // SAFETY: register-only; `s0`/`s1` are declared clobbered; no memory access.
    unsafe {
        core::arch::asm!(
            "2:",
            "vadd.f32 s0, s0, s1",
            "subs {n}, #1",
            "bne 2b",
            n = inout(reg) CALIBRATION_ITERATIONS => _,
            out("s0") _,
            out("s1") _,
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
    int_ticks
}

/// `round(ticks * 2 * iterations / (int_loop_ticks * steps))`.
fn instructions_per_step(ticks: u32, int_loop_ticks: u32, steps: usize) -> u32 {
    let num = u64::from(ticks) * 2 * u64::from(CALIBRATION_ITERATIONS);
    let den = u64::from(int_loop_ticks) * steps as u64;
    if den == 0 {
        return 0;
    }
    u32::try_from((num + den / 2) / den).unwrap_or(u32::MAX)
}

/// Width and depth of the model's neural scalers (`(0, 0)` without any).
fn scaler_shape(model: &Model<PARAM_CAPACITY>) -> (u32, u32) {
    match &model.body {
        Body::NemmLight { b_fl, .. } | Body::Nemm { b_fl, .. } => {
            (u32::from(b_fl.mlp.hidden), u32::from(b_fl.mlp.layers))
        }
        Body::Sem(_) | Body::LinearEmm(_) => (0, 0),
    }
}

/// Bit-for-bit comparison of the kernel and the portable code of one state scaler, compiled
/// as the estimator compiles it. Returns the number of mismatching inputs.
#[allow(clippy::too_many_arguments)] // the compile arguments of the estimator, plus output
fn check_scaler(
    console: &mut Console,
    slot: &mut Option<CompiledScaler<PARAM_CAPACITY>>,
    name: &str,
    scaler: &Scaler<PARAM_CAPACITY>,
    p_ini: f32,
    u_scale: f32,
    alpha: f32,
    alpha_scale: f32,
    inputs: u32,
) -> u32 {
    let Some(c) = CompiledScaler::compile(scaler, p_ini, u_scale, alpha, alpha_scale) else {
        let mut l = Line::new();
        l.str("error").ks("kind", "compile").ks("scaler", name);
        fail(console, &mut l, report::EXIT_BAD_WEIGHTS)
    };
    let c = slot.insert(c);
    const SPECIAL: [f32; 8] = [0.0, -0.0, 1e-30, -1e-30, 1e-3, -1e-3, 1e3, -1e3];
    let mut mismatches = 0u32;
    let mut first: Option<f32> = None;
    let n = inputs.max(1);
    for k in 0..inputs + SPECIAL.len() as u32 {
        let u = match SPECIAL.get(k as usize) {
            Some(&s) => s * u_scale,
            None => {
                let i = k - SPECIAL.len() as u32;
                u_scale * (3.0 * i as f32 / n as f32 - 1.5)
            }
        };
        let (a, b) = (
            nemm_core::testing::scaler_raw(c, black_box(u)),
            nemm_core::testing::scaler_raw_portable(c, black_box(u)),
        );
        if a.to_bits() != b.to_bits() {
            mismatches += 1;
            first.get_or_insert(u);
        }
    }
    let mut l = Line::new();
    l.str("kernel-check")
        .ks("scaler", name)
        .kv("hidden", u32::from(scaler.mlp.hidden))
        .kv("layers", u32::from(scaler.mlp.layers))
        .kv("inputs", inputs + SPECIAL.len() as u32)
        .kv("mismatches", mismatches);
    if let Some(u) = first {
        l.kx("first_u_bits", u.to_bits());
    }
    console.write(l.finish());
    mismatches
}

/// The model (example or weights slot) into its static, in a frame of its own (`decode`
/// and the example builder take a large one; see [`build_estimator`]).
#[inline(never)]
fn load_model(
    console: &mut Console,
    opt: &Options,
) -> (
    &'static Model<PARAM_CAPACITY>,
    (StoredTables, &'static [u8]),
) {
    // The model's static, filled in place (a decoded model by value would take its size on
    // the stack, which the observer's statics leave short).
    const EMPTY: Model<PARAM_CAPACITY> = Model::empty();
    let Some(model) = MODEL.init_with(|| EMPTY) else {
        board::exit(report::EXIT_USAGE)
    };
    let mut stored = (StoredTables::EMPTY, &[][..]);
    match opt.example {
        Some(kind) => {
            match nemm_core::testing::example_model::<PARAM_CAPACITY>(kind, opt.hidden, opt.layers)
            {
                Some(m) => *model = m,
                None => {
                    let mut l = Line::new();
                    l.str("error")
                        .ks("kind", "example-over-capacity")
                        .kv("hidden", u32::from(opt.hidden))
                        .kv("layers", u32::from(opt.layers))
                        .kv("capacity", PARAM_CAPACITY as u32);
                    fail(console, &mut l, report::EXIT_USAGE)
                }
            }
        }
        None => match slot::blob(board::weights_slot()) {
            Err(e) => {
                let mut l = Line::new();
                report::slot_error(&mut l, &e);
                fail(console, &mut l, report::EXIT_BAD_WEIGHTS)
            }
            Ok(blob) => match decode_into(blob, model) {
                Ok(tables) => stored = (tables, blob),
                Err(e) => {
                    let mut l = Line::new();
                    report::decode_error(&mut l, &e);
                    fail(console, &mut l, report::EXIT_BAD_WEIGHTS)
                }
            },
        },
    }
    if opt.lost_motion {
        if model.kind() == ModelKind::Sem {
            let mut l = Line::new();
            l.str("error").ks("kind", "lost-motion-on-sem");
            fail(console, &mut l, report::EXIT_USAGE)
        }
        model.lost_motion = Some(nemm_core::testing::EXAMPLE_LOST_MOTION);
    }
    (model, stored)
}

/// [`LOST_MOTION_SUFFIX`] if `model` has a lost-motion element, else empty.
fn kind_suffix(model: &Model<PARAM_CAPACITY>) -> &'static str {
    if model.lost_motion.is_some() {
        LOST_MOTION_SUFFIX
    } else {
        ""
    }
}

/// `Estimator::new` into `slot`, in a frame of its own: inlined into `main`, its temporaries
/// (an estimator with two tables is ~30 KiB) would add to the frame that `decode` already
/// makes large, and overflow the 192 KiB of RAM.
#[inline(never)]
fn build_estimator<'a>(
    slot: &'a mut Option<nemm_firmware::FwEstimator>,
    model: &Model<PARAM_CAPACITY>,
    cfg: EstimatorConfig,
) -> Result<&'a mut nemm_firmware::FwEstimator, nemm_core::EstimatorError> {
    // The empty estimator as one constant, loaded in place: no estimator-sized temporary on
    // the stack (the observer's statics leave it short).
    const EMPTY: nemm_firmware::FwEstimator = nemm_firmware::FwEstimator::empty();
    *slot = None;
    let est = slot.insert(EMPTY);
    est.load(model, cfg)?;
    Ok(est)
}

#[entry]
fn main() -> ! {
    board::init();
    let mut console = Console::open();
    let opt = parse_options(&mut console);
    let (model, stored) = load_model(&mut console, &opt);
    let Ok(trace) = Trace::parse(board::trace_bytes()) else {
        let mut l = Line::new();
        l.str("error").ks("kind", "trace");
        fail(&mut console, &mut l, report::EXIT_USAGE)
    };
    let (hidden, layers) = scaler_shape(model);
    if opt.check > 0 {
        check_scalers(&mut console, model, trace.oil_loss, opt.check);
    }
    let velocities = sensor_velocities(trace);
    // Parity runs start from a fresh estimator, so that the host replays exactly the
    // printed velocities.
    let warmup_steps = if opt.parity > 0 { 0 } else { opt.warmup };
    let (warmup, rest) = velocities.split_at(warmup_steps);
    let n_measured = if opt.parity > 0 {
        opt.parity
    } else {
        opt.steps
    };
    let measured = rest.get(..n_measured).unwrap_or(rest);
    let mut syst = start_systick();
    let int_loop_ticks = if opt.calibrate && opt.parity == 0 {
        calibrate(&mut console)
    } else {
        // The factor QEMU's `-icount shift=0` gives on mps2-an386 (25 MHz SysTick).
        2 * CALIBRATION_ITERATIONS / 40
    };
    let Some(est_slot) = ESTIMATOR.init(None) else {
        board::exit(report::EXIT_USAGE)
    };
    if opt.observer {
        let forces = model_forces(&mut console, est_slot, model, trace.oil_loss, velocities);
        let (fw, fm) = forces.split_at(warmup.len());
        let run = RunName {
            kind: model.kind().name(),
            kind_suffix: kind_suffix(model),
            integrator: model.integrator.name(),
            mode: Mode::Exact,
            hidden,
            layers,
        };
        let observer = observer_run(
            &mut console,
            (model, &stored),
            &run,
            (warmup, fw),
            (measured, fm.get(..measured.len()).unwrap_or(fm)),
            int_loop_ticks,
        );
        if let (Some(est), Some(levels)) = (est_slot.as_mut(), observer.levels()) {
            level_step_run(&mut console, est, levels, &run, measured, int_loop_ticks);
        }
        board::exit(report::EXIT_DONE)
    }
    for &integrator in opt.integrators {
        let cfg = EstimatorConfig {
            integrator: Some(integrator),
            mode: opt.mode.eval_mode(),
            ..EstimatorConfig::new(trace.oil_loss)
        };
        let (built, build_ticks) = long_ticks(&mut syst, || build_estimator(est_slot, model, cfg));
        let est = match built {
            Ok(e) => e,
            Err(e) => {
                let mut l = Line::new();
                report::estimator_error(&mut l, &e);
                fail(&mut console, &mut l, report::EXIT_BAD_WEIGHTS)
            }
        };
        // `build_ticks`: estimator construction (in table mode: building and checking the
        // tables), in SysTick ticks.
        for &v in warmup {
            black_box(step_v(est, black_box(v)));
        }
        let run = RunName {
            kind: model.kind().name(),
            kind_suffix: kind_suffix(model),
            integrator: integrator.name(),
            mode: opt.mode,
            hidden,
            layers,
        };
        if opt.parity > 0 {
            parity_run(&mut console, est, &run, warmup.len(), measured);
            continue;
        }
        let (ticks, baseline) = time_steps(est, measured);
        let mut l = Line::new();
        l.str("bench")
            .ks("kind", run.kind)
            .str(run.kind_suffix)
            .ks("integrator", run.integrator)
            .ks("mode", run.mode.name())
            .kv("hidden", hidden)
            .kv("layers", layers)
            .kv("steps", measured.len() as u32)
            .kv("ticks", ticks)
            .kv("baseline_ticks", baseline)
            .kv(
                "instructions_per_step",
                instructions_per_step(
                    ticks.saturating_sub(baseline),
                    int_loop_ticks,
                    measured.len(),
                ),
            )
            .kv("held", est.diagnostics().held_samples)
            .kv("resets", est.diagnostics().resets);
        console.write(l.finish());
        if opt.mode == Mode::Table {
            table_line(&mut console, est, &run, build_ticks);
        }
    }
    board::exit(report::EXIT_DONE)
}

/// The options from the command line; an invalid one is reported and ends the program.
fn parse_options(console: &mut Console) -> Options {
    let mut opt = Options {
        mode: Mode::Exact,
        steps: 2000,
        warmup: MAX_WARMUP_STEPS,
        integrators: &[Integrator::Rk4, Integrator::Rk3],
        example: None,
        hidden: 16,
        layers: 5,
        check: 0,
        parity: 0,
        calibrate: true,
        observer: false,
        lost_motion: false,
    };
    let mut args = [0u8; board::ARGS_CAPACITY];
    for arg in board::args(&mut args)
        .unwrap_or("")
        .split_ascii_whitespace()
    {
        if !opt.apply(arg) {
            let mut l = Line::new();
            l.str("error").ks("kind", "bad-option").ks("option", arg);
            fail(console, &mut l, report::EXIT_USAGE)
        }
    }
    opt
}

/// The `check=N` option: the kernel check of every neural state scaler of `model` at `n`
/// inputs and the level `alpha`; ends the program if any mismatch. A coefficient with a
/// cumulative scaler (`Model::cumulative`) has no MLP kernel and is not checked.
fn check_scalers(console: &mut Console, model: &Model<PARAM_CAPACITY>, alpha: f32, n: u32) {
    let Some(slot) = COMPILED.init(None) else {
        board::exit(report::EXIT_USAGE)
    };
    let sc = &model.scales;
    let mut bad = 0;
    let cumulative = &model.cumulative;
    if let Body::NemmLight { emm, b_fl } | Body::Nemm { emm, b_fl, .. } = &model.body {
        if cumulative.b_fl.is_none() {
            bad += check_scaler(
                console,
                slot,
                "b_fl",
                b_fl,
                emm.b_fl_ns_per_m,
                sc.velocity_m_s,
                alpha,
                sc.alpha,
                n,
            );
        }
    }
    if let Body::Nemm { emm, k_pr, .. } = &model.body {
        if cumulative.k_pr.is_none() {
            bad += check_scaler(
                console,
                slot,
                "k_pr",
                k_pr,
                emm.k_pr_n_per_m,
                sc.x_pr_m,
                alpha,
                sc.alpha,
                n,
            );
        }
    }
    if bad > 0 {
        board::exit(EXIT_CHECK_FAILED)
    }
}

/// The trace's velocities through the real sensor path, warm-up and measured steps (a
/// sample without one holds the previous).
fn sensor_velocities(trace: Trace<'static>) -> &'static [f32] {
    let Some(velocities) = VELOCITIES.init([0.0; MAX_STEPS + MAX_WARMUP_STEPS]) else {
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
    velocities
}

/// SysTick free running on the core clock over its full range.
fn start_systick() -> SYST {
    // SAFETY: this program is the only user of SysTick.
    let mut syst = unsafe { cortex_m::Peripherals::steal() }.SYST;
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(SYST_RANGE - 1);
    syst.clear_current();
    syst.enable_counter();
    syst
}

/// What the lines of one integrator's run name: the model kind, the integrator, the
/// evaluation mode and the scalers' width and depth.
struct RunName {
    kind: &'static str,
    /// [`LOST_MOTION_SUFFIX`] if the model has a lost-motion element, else empty: the
    /// lines' `kind=` reads e.g. `nemm+lm`.
    kind_suffix: &'static str,
    integrator: &'static str,
    mode: Mode,
    hidden: u32,
    layers: u32,
}

/// The `parity=N` run of one integrator: every measured step's velocity, force and flag
/// bits, framed by a header and the FNV-1a of the force bits.
fn parity_run(
    console: &mut Console,
    est: &mut nemm_firmware::FwEstimator,
    run: &RunName,
    warmup: usize,
    measured: &[f32],
) {
    let mut l = Line::new();
    l.str("parity")
        .ks("kind", run.kind)
        .str(run.kind_suffix)
        .ks("integrator", run.integrator)
        .ks("mode", run.mode.name())
        .kv("hidden", run.hidden)
        .kv("layers", run.layers)
        .kv("warmup", warmup as u32)
        .kv("steps", measured.len() as u32);
    console.write(l.finish());
    let mut fnv = 0x811c_9dc5u32;
    for (k, &v) in measured.iter().enumerate() {
        let e = step_v(est, v);
        let bits = e.force_n.to_bits();
        for byte in bits.to_le_bytes() {
            fnv = (fnv ^ u32::from(byte)).wrapping_mul(0x0100_0193);
        }
        let mut l = Line::new();
        l.str("p ")
            .dec(k as u32)
            .str(" ")
            .hex_bare(v.to_bits(), 8)
            .str(" ")
            .hex_bare(bits, 8)
            .str(" ")
            .hex_bare(u32::from(e.flags.0), 2);
        console.write(l.finish());
    }
    let mut l = Line::new();
    l.str("parity-end")
        .ks("integrator", run.integrator)
        .kv("steps", measured.len() as u32)
        .kx("fnv", fnv);
    console.write(l.finish());
}

/// SysTick ticks of the `measured` steps and of the same loop around an empty body:
/// `(ticks, baseline)`. Each step is timed on its own: the 24-bit counter wraps after
/// 16.7 M ticks (671 M instructions), far less than a whole run of slow steps.
#[inline(always)]
fn time_steps(est: &mut nemm_firmware::FwEstimator, measured: &[f32]) -> (u32, u32) {
    let mut baseline = 0u32;
    for &v in measured {
        let start = SYST::get_current();
        black_box(black_box(v));
        baseline = baseline.wrapping_add(ticks_since(start));
    }
    let mut ticks = 0u32;
    for &v in measured {
        let start = SYST::get_current();
        black_box(step_v(est, black_box(v)));
        ticks = ticks.wrapping_add(ticks_since(start));
    }
    (ticks, baseline)
}

/// The model's force at level `alpha` for each of `velocities` (exact mode, from rest): the
/// measured force the observer benchmark feeds.
fn model_forces(
    console: &mut Console,
    slot: &mut Option<nemm_firmware::FwEstimator>,
    model: &Model<PARAM_CAPACITY>,
    alpha: f32,
    velocities: &[f32],
) -> &'static [f32] {
    let Some(forces) = FORCES.init([0.0; MAX_STEPS + MAX_WARMUP_STEPS]) else {
        board::exit(report::EXIT_USAGE)
    };
    let est = match build_estimator(slot, model, EstimatorConfig::new(alpha)) {
        Ok(e) => e,
        Err(e) => {
            let mut l = Line::new();
            report::estimator_error(&mut l, &e);
            fail(console, &mut l, report::EXIT_BAD_WEIGHTS)
        }
    };
    for (f, &v) in forces.iter_mut().zip(velocities) {
        *f = step_v(est, v).force_n;
    }
    forces
}

/// One observer step, not inlined: what the `observer` run times and the cycle model's trace
/// (`xtask/src/cycles.rs`) stops at.
#[inline(never)]
fn observer_step(observer: &mut FwObserver, velocity_m_s: f32, force_n: f32) -> AlphaEstimate {
    observer.step(Sample::new(velocity_m_s).with_force(force_n))
}

/// The `observer=1` run: the firmware's observer built in its static from `model`, stepped
/// over the `warmup` (velocity, force) samples, then each `measured` step timed on its own;
/// the `observer` line.
fn observer_run(
    console: &mut Console,
    (model, (tables, blob)): (&Model<PARAM_CAPACITY>, &(StoredTables, &'static [u8])),
    run: &RunName,
    warmup: (&[f32], &[f32]),
    measured: (&[f32], &[f32]),
    int_loop_ticks: u32,
) -> &'static FwObserver {
    // The empty observer as one constant, copied into the static (no stack temporary).
    const EMPTY: FwObserver = FwObserver::empty();
    const NO_LEVELS: nemm_firmware::FwLevels = nemm_firmware::FwLevels::empty();
    let (Some(observer), Some(levels)) =
        (OBSERVER.init_with(|| EMPTY), LEVELS.init_with(|| NO_LEVELS))
    else {
        board::exit(report::EXIT_USAGE)
    };
    if let Err(e) = observer.load(levels, model, tables, blob) {
        let mut l = Line::new();
        report::observer_error(&mut l, &e);
        fail(console, &mut l, report::EXIT_BAD_WEIGHTS)
    }
    for (&v, &f) in warmup.0.iter().zip(warmup.1) {
        black_box(observer_step(observer, black_box(v), black_box(f)));
    }
    let (velocities, forces) = measured;
    let n = velocities.len().min(forces.len());
    let mut baseline = 0u32;
    for (&v, &f) in velocities.iter().zip(forces) {
        let start = SYST::get_current();
        black_box((black_box(v), black_box(f)));
        baseline = baseline.wrapping_add(ticks_since(start));
    }
    let (mut ticks, mut held, mut max_ticks) = (0u32, 0u32, 0u32);
    let solves_before = observer.solves();
    for (&v, &f) in velocities.iter().zip(forces) {
        let start = SYST::get_current();
        let e = black_box(observer_step(observer, black_box(v), black_box(f)));
        let step_ticks = ticks_since(start);
        ticks = ticks.wrapping_add(step_ticks);
        max_ticks = max_ticks.max(step_ticks);
        if e.flags.contains(ObserverFlags::HELD) {
            held += 1;
        }
    }
    let closes = observer.solves().wrapping_sub(solves_before);
    let one_baseline = baseline / n.max(1) as u32;
    // The first close of a block of stroke cycles (the heaviest step: the window's sums and
    // fits), stepping on over the trace again (untimed but for the step itself) until one
    // happens, at most CLOSE_PASSES passes.
    let mut close = None;
    'passes: for _ in 0..CLOSE_PASSES {
        for (&v, &f) in velocities.iter().zip(forces) {
            let before = observer.solves();
            let start = SYST::get_current();
            black_box(observer_step(observer, black_box(v), black_box(f)));
            let step_ticks = ticks_since(start);
            if observer.solves() != before {
                close = Some(step_ticks);
                break 'passes;
            }
        }
    }
    let mut l = Line::new();
    l.str("observer")
        .ks("kind", run.kind)
        .str(run.kind_suffix)
        .ks("integrator", run.integrator)
        .kv("levels", observer.points() as u32)
        .ks(
            "levels_from",
            if observer.on_levels() {
                "blob"
            } else {
                "exact"
            },
        )
        .kv("model_steps", observer.evaluations_per_step() as u32)
        .kv("bytes", observer_bytes(observer))
        .kv("hidden", run.hidden)
        .kv("layers", run.layers)
        .kv("steps", n as u32)
        .kv("ticks", ticks)
        .kv("baseline_ticks", baseline)
        .kv(
            "instructions_per_step",
            instructions_per_step(ticks.saturating_sub(baseline), int_loop_ticks, n),
        )
        .kv("held", held);
    console.write(l.finish());
    let instructions =
        |t: u32| instructions_per_step(t.saturating_sub(one_baseline), int_loop_ticks, 1);
    let mut l = Line::new();
    l.str("observer-steps")
        .kv("closes", closes)
        .kv("max_step_ticks", max_ticks)
        .kv("max_step_instructions", instructions(max_ticks));
    match close {
        Some(t) => {
            l.kv("close_step_ticks", t)
                .kv("close_step_instructions", instructions(t));
        }
        None => {
            l.str(" close_step=none");
        }
    }
    console.write(l.finish());
    observer
}

/// Passes over the measured trace the observer benchmark steps on at most to meet a close
/// of a block of stroke cycles.
const CLOSE_PASSES: usize = 20;

/// The observer's RAM \[B\]: `FwObserver` and, when it steps on them, its level tables.
fn observer_bytes(observer: &FwObserver) -> u32 {
    let levels = if observer.on_levels() {
        core::mem::size_of::<nemm_firmware::FwLevels>()
    } else {
        0
    };
    (core::mem::size_of::<FwObserver>() + levels) as u32
}

/// One estimator step of the velocity alone (`Estimator::step` of a sample without a
/// level, which is never refused: the other arm is never taken).
#[inline(always)]
fn step_v(est: &mut nemm_firmware::FwEstimator, velocity_m_s: f32) -> Estimate {
    est.step(Sample::new(velocity_m_s)).unwrap_or(Estimate {
        force_n: f32::NAN,
        flags: Flags(Flags::NO_MODEL),
    })
}

/// One estimator step at a level per sample on the level tables, not inlined: what the
/// `level-step` line times.
#[inline(never)]
fn level_step(est: &mut nemm_firmware::FwEstimator, velocity_m_s: f32, alpha: f32) -> f32 {
    est.step(Sample::new(velocity_m_s).with_alpha(alpha))
        .map_or(f32::NAN, |e| e.force_n)
}

/// The estimator with a level per sample on the observer's level tables (attached to it:
/// `Estimator::attach_levels`, then `Estimator::step` with an `alpha`), the level changing
/// every sample (a sweep over the
/// levels' range, the worst case: the coefficients at the state are re-read each step):
/// each `measured` step timed on its own; the `level-step` line. Nothing without level
/// tables.
fn level_step_run(
    console: &mut Console,
    est: &mut nemm_firmware::FwEstimator,
    levels: &'static nemm_firmware::FwLevels,
    run: &RunName,
    measured: &[f32],
    int_loop_ticks: u32,
) {
    let (Some(&lo), Some(&hi)) = (levels.alphas().first(), levels.alphas().last()) else {
        return;
    };
    if est.attach_levels(levels).is_err() {
        return;
    }
    est.reset();
    let alpha = |k: usize| lo + (hi - lo) * (k % 97) as f32 / 96.0;
    let mut baseline = 0u32;
    for (k, &v) in measured.iter().enumerate() {
        let start = SYST::get_current();
        black_box((black_box(v), black_box(alpha(k))));
        baseline = baseline.wrapping_add(ticks_since(start));
    }
    let (mut ticks, mut failed) = (0u32, 0u32);
    for (k, &v) in measured.iter().enumerate() {
        let a = alpha(k);
        let start = SYST::get_current();
        let f = black_box(level_step(est, black_box(v), black_box(a)));
        ticks = ticks.wrapping_add(ticks_since(start));
        if !f.is_finite() {
            failed += 1;
        }
    }
    let n = measured.len();
    let mut l = Line::new();
    l.str("level-step")
        .ks("kind", run.kind)
        .str(run.kind_suffix)
        .ks("integrator", run.integrator)
        .kv("levels", levels.len() as u32)
        .kv("steps", n as u32)
        .kv("ticks", ticks)
        .kv("baseline_ticks", baseline)
        .kv(
            "instructions_per_step",
            instructions_per_step(ticks.saturating_sub(baseline), int_loop_ticks, n),
        )
        .kv("failed", failed);
    console.write(l.finish());
}

/// The `table` line of a table-mode run: the tables' count, bytes, worst relative error
/// and kinks, and the ticks of building the estimator.
fn table_line(
    console: &mut Console,
    est: &nemm_firmware::FwEstimator,
    run: &RunName,
    build_ticks: u32,
) {
    let (tables, bytes) = est.table_bytes();
    let acc = est.table_accuracy();
    let mut l = Line::new();
    l.str("table")
        .ks("kind", run.kind)
        .str(run.kind_suffix)
        .ks("integrator", run.integrator)
        .kv("segments", nemm_firmware::TABLE_SEGMENTS as u32)
        .kv("tables", tables as u32)
        .kv("table_bytes", bytes as u32)
        .kv(
            "max_rel_error_ppb",
            report::ppb(acc.map_or(0.0, |a| a.max_rel_error)),
        )
        .kv("kinks", acc.map_or(0, |a| a.kinks as u32))
        .kv("build_ticks", build_ticks);
    console.write(l.finish());
}
