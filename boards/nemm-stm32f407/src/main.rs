//! The NEMM damper-force estimator on an STM32F407 (Cortex-M4F, 168 MHz), RTIC 2.
//!
//! | context | priority | job |
//! |---------|----------|-----|
//! | `init` | - | clock tree (168 MHz from HSE, [`clock`]), DWT cycle counter, weights from the flash slot, estimator (table mode unless the `exact` feature), SPI2 sensor, DAC, LEDs, TIM2 at 10 kHz |
//! | `sample` (TIM2 update) | 1 | read the stroke sensor through `nemm_firmware`'s driver, step the estimator, write the force to the DAC, count faults, overruns and the step's cycles |
//! | `idle` | 0 | a `status` line every second (RTT on the board, semihosting in QEMU); in QEMU, a `summary` and the exit after [`QEMU_RUN_STEPS`] steps |
//!
//! The sample period is the one of the `nemm-firmware` application
//! (`nemm_firmware::pipeline::run_period`: the same sensor driver, fault handling and
//! estimator step); only the board around it differs. The 10 kHz task shares its counters
//! with `idle` through atomics ([`Status`]), so the logger never blocks it.
//!
//! Every step reads the DWT cycle counter at its start and end: `worst_step_cycles` is the
//! longest step since boot in core cycles (the budget is 16,800 at 168 MHz and 10 kHz) and
//! `overruns` counts the steps that ended after the next TIM2 update (the update flag set
//! again). The `start` line's `boot_cycles` is the boot from the end of the clock set-up
//! (where the counter starts) to the sample timer's start: the measured counterpart of
//! `cargo xtask build-target`'s estimate. QEMU does not model the cycle counter: there the
//! cycle figures read 0. The lines
//! also carry `stack_used`, the stack's high-water mark by stack painting (deepest at boot,
//! while the model and the estimator are built).
#![no_std]
#![no_main]

mod clock;
mod console;
mod io;
mod spi;

use core::sync::atomic::AtomicU32;

/// Steps of a QEMU run (`qemu` feature) before the summary and the exit: 2 s at 10 kHz.
pub const QEMU_RUN_STEPS: u32 = 20_000;
/// Steps between two `status` lines: one second.
pub const STATUS_STEPS: u32 = nemm_firmware::SAMPLE_RATE_HZ;
/// The damper's oil loss alpha the estimator runs at (the bench recordings' 15 %, as in the
/// `nemm-firmware` replay); set the damper's own value here.
pub const OIL_LOSS: f32 = 0.15;

/// TIM2's input clock: 84 MHz on the board ([`clock::TIM2_CLOCK_HZ`]); QEMU's netduinoplus2
/// counts its timers at 1 GHz of emulated time (one instruction per ns with
/// `-icount shift=0`) whatever RCC says.
pub const TIMER_CLOCK_HZ: u32 = if cfg!(feature = "qemu") {
    1_000_000_000
} else {
    clock::TIM2_CLOCK_HZ
};

/// Core cycles per sample period at 168 MHz: the step's budget.
pub const PERIOD_CYCLES: u32 = clock::SYSCLK_HZ / nemm_firmware::SAMPLE_RATE_HZ;

/// Counters of the 10 kHz task, read by `idle` (and by a debugger: `NEMM_STATUS` is a
/// symbol of the image).
pub struct Status {
    /// Steps run.
    pub steps: AtomicU32,
    /// Longest step since boot \[core cycles\] (DWT CYCCNT).
    pub worst_step_cycles: AtomicU32,
    /// Cycles of the last step.
    pub last_step_cycles: AtomicU32,
    /// Steps that ended after the next period had started.
    pub overruns: AtomicU32,
    /// Failed SPI transactions and "no new conversion" answers.
    pub sensor_errors: AtomicU32,
    /// Conversions flagged invalid.
    pub invalid_samples: AtomicU32,
    /// Bits of the last force estimate \[N\].
    pub force_bits: AtomicU32,
}

/// The counters of the run.
#[no_mangle]
pub static NEMM_STATUS: Status = Status {
    steps: AtomicU32::new(0),
    worst_step_cycles: AtomicU32::new(0),
    last_step_cycles: AtomicU32::new(0),
    overruns: AtomicU32::new(0),
    sensor_errors: AtomicU32::new(0),
    invalid_samples: AtomicU32::new(0),
    force_bits: AtomicU32::new(0),
};

/// A hard fault turns the fault LED on and stops (QEMU: exits with failure).
#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    stop()
}

/// The image links no panic path (`tests/tests/qemu_no_panic.rs` checks its symbols); if
/// one ever ran, it would stop like a hard fault.
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    stop()
}

/// Fault LED on, then sleep (QEMU: semihosting exit with failure).
fn stop() -> ! {
    // SAFETY: a single BSRR write of PD14 (the fault LED); the LED pins were set up in
    // `init`, and if not the write only latches the output register.
    unsafe {
        (*stm32f4::stm32f407::GPIOD::ptr())
            .bsrr()
            .write(|w| w.bs14().set_bit())
    };
    #[cfg(feature = "qemu")]
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[rtic::app(device = stm32f4::stm32f407, peripherals = true)]
mod app {
    use crate::console::Console;
    use crate::io::{ForceDac, Leds, HEARTBEAT_STEPS};
    use crate::spi::{ChipSelect, CycleDelay, Spi2};
    use crate::{
        clock, Status, NEMM_STATUS, OIL_LOSS, PERIOD_CYCLES, STATUS_STEPS, TIMER_CLOCK_HZ,
    };
    use core::sync::atomic::Ordering;
    use cortex_m::peripheral::DWT;
    use embedded_hal_bus::spi::ExclusiveDevice;
    use nemm_core::{decode_into, EstimatorConfig, Model};
    use nemm_firmware::pipeline::{self, SensorCounters};
    use nemm_firmware::report::{self, Line};
    use nemm_firmware::sensor::StrokeSensor;
    use nemm_firmware::{slot, FwEstimator, StaticSlot, PARAM_CAPACITY, SAMPLE_RATE_HZ};
    use stm32f4::stm32f407::{FLASH, RCC, TIM2};

    /// The stroke sensor: `nemm_firmware`'s driver on SPI2 with chip select PB12.
    type Sensor = StrokeSensor<ExclusiveDevice<Spi2, ChipSelect, CycleDelay>>;

    /// The decoded model (the estimator is built from it).
    static MODEL: StaticSlot<Model<PARAM_CAPACITY>> = StaticSlot::new();
    /// The estimator, lent to the 10 kHz task.
    static ESTIMATOR: StaticSlot<FwEstimator> = StaticSlot::new();

    /// Everything the 10 kHz task owns.
    pub struct SampleLoop {
        sensor: Sensor,
        estimator: &'static mut FwEstimator,
        dac: ForceDac,
        leds: Leds,
        timer: TIM2,
        counters: SensorCounters,
        worst: u32,
    }

    #[shared]
    struct Shared {}

    #[local]
    struct Local {
        sample_loop: Option<SampleLoop>,
        console: Console,
    }

    /// Reports `line`, lights the fault LED and leaves the estimator stopped.
    fn stopped(mut console: Console, leds: Leds, line: &mut Line) -> (Shared, Local) {
        console.write(line.finish());
        leds.fault();
        (
            Shared {},
            Local {
                sample_loop: None,
                console,
            },
        )
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp = cx.device;
        let mut cp = cx.core;
        let mut console = Console::open();
        let leds = Leds::new(&dp.RCC, &dp.GPIOD);
        let mut line = Line::new();
        line.str("boot")
            .ks("firmware", env!("CARGO_PKG_NAME"))
            .ks("version", env!("CARGO_PKG_VERSION"))
            .ks("board", "stm32f407")
            .kv("capacity", PARAM_CAPACITY as u32);
        console.write(line.finish());
        let mut error = Line::new();
        if !start_clock(&mut console, &dp.RCC, &dp.FLASH, &mut error) {
            return stopped(console, leds, &mut error);
        }
        cp.DCB.enable_trace();
        cp.DWT.set_cycle_count(0);
        cp.DWT.enable_cycle_counter();
        let Some(estimator) = build_estimator(&mut console, &mut error) else {
            return stopped(console, leds, &mut error);
        };
        let cal = nemm_firmware::stroke_calibration();
        let bus = Spi2::new(dp.SPI2, &dp.RCC, &dp.GPIOB);
        let cs = ChipSelect::new(&dp.RCC, &dp.GPIOB);
        let Ok(device) = ExclusiveDevice::new(bus, cs, CycleDelay);
        let sensor = StrokeSensor::new(device, cal);
        let dac = ForceDac::new(dp.DAC, &dp.RCC, &dp.GPIOA);
        let timer = sample_timer(dp.TIM2, &dp.RCC);
        let mut l = Line::new();
        l.str("start")
            .kv("rate_hz", SAMPLE_RATE_HZ)
            .ks("timer", "TIM2")
            .kv("timer_period", TIMER_CLOCK_HZ / SAMPLE_RATE_HZ)
            .kv("budget_cycles", PERIOD_CYCLES)
            .kv("boot_cycles", DWT::cycle_count());
        console.write(l.finish());
        timer.cr1().modify(|_, w| w.cen().enabled());
        (
            Shared {},
            Local {
                sample_loop: Some(SampleLoop {
                    sensor,
                    estimator,
                    dac,
                    leds,
                    timer,
                    counters: SensorCounters::default(),
                    worst: 0,
                }),
                console,
            },
        )
    }

    /// The clock tree at 168 MHz from the crystal, and the `clock` line; `false`, with the
    /// error line in `error`, if the set-up failed.
    fn start_clock(console: &mut Console, rcc: &RCC, flash: &FLASH, error: &mut Line) -> bool {
        if let Err(e) = clock::configure(rcc, flash) {
            error.str("clock-error").ks("kind", e.name());
            return false;
        }
        let mut l = Line::new();
        l.str("clock")
            .kv("sysclk_hz", clock::SYSCLK_HZ)
            .kv("hse_hz", clock::HSE_HZ)
            .kv("tim2_hz", TIMER_CLOCK_HZ)
            .ks(
                "ready_waits",
                if cfg!(feature = "qemu") {
                    "skipped"
                } else {
                    "done"
                },
            );
        console.write(l.finish());
        true
    }

    /// The estimator at [`OIL_LOSS`], from the flashed weights slot decoded once into its
    /// static, in place, and built in place in its own (with the blob's stored tables at
    /// this level, if it has them: no table build at boot); writes the `weights` line with
    /// the build's cycles. `None`, with the error line in `error`, for a missing or bad blob,
    /// a model of another rate or an estimator error.
    fn build_estimator(
        console: &mut Console,
        error: &mut Line,
    ) -> Option<&'static mut FwEstimator> {
        let blob = match slot::blob(slot::flashed()) {
            Ok(b) => b,
            Err(e) => {
                report::slot_error(error, &e);
                return None;
            }
        };
        let Some(model) = MODEL.init(Model::empty()) else {
            crate::stop() // init runs once
        };
        let tables = match decode_into(blob, model) {
            Ok(tables) => tables,
            Err(e) => {
                report::decode_error(error, &e);
                return None;
            }
        };
        let model = &*model;
        if !report::check_rate(error, model.dt_s) {
            return None;
        }
        let boot_cycles = DWT::cycle_count();
        let cfg = EstimatorConfig {
            mode: nemm_firmware::eval_mode(!cfg!(feature = "exact")),
            ..EstimatorConfig::new(OIL_LOSS)
        };
        // Loaded in place into its static: nothing of the estimator's size is on the stack.
        let Some(estimator) = ESTIMATOR.init(FwEstimator::empty()) else {
            crate::stop() // init runs once
        };
        if let Err(e) = estimator.load_with_tables(model, cfg, &tables, blob) {
            report::estimator_error(error, &e);
            return None;
        }
        let build_cycles = DWT::cycle_count().wrapping_sub(boot_cycles);
        let mut l = Line::new();
        report::weights_ok(&mut l, model, blob.len(), estimator);
        l.kv("build_cycles", build_cycles);
        console.write(l.finish());
        Some(estimator)
    }

    /// TIM2 up-counting with an update event (and its interrupt) every
    /// `1 / SAMPLE_RATE_HZ`, not yet started.
    fn sample_timer(timer: TIM2, rcc: &RCC) -> TIM2 {
        rcc.apb1enr().modify(|_, w| w.tim2en().set_bit());
        timer.psc().write(|w| w.psc().set(0));
        timer
            .arr()
            .write(|w| w.arr().set(TIMER_CLOCK_HZ / SAMPLE_RATE_HZ - 1));
        timer.egr().write(|w| w.ug().update());
        timer.sr().write(|w| w.uif().clear());
        timer.dier().write(|w| w.uie().enabled());
        timer
    }

    /// The 10 kHz step.
    #[task(binds = TIM2, priority = 1, local = [sample_loop])]
    fn sample(cx: sample::Context) {
        if let Some(s) = cx.local.sample_loop {
            s.period();
        }
    }

    impl SampleLoop {
        #[inline(always)]
        fn period(&mut self) {
            let start = DWT::cycle_count();
            self.timer.sr().write(|w| w.uif().clear());
            self.leds.step(true);
            let out = pipeline::run_period(&mut self.sensor, self.estimator, &mut self.counters);
            self.dac.publish(out.estimate.force_n);
            let st: &Status = &NEMM_STATUS;
            let steps = st.steps.load(Ordering::Relaxed).wrapping_add(1);
            if steps % HEARTBEAT_STEPS == 0 {
                self.leds.toggle_heartbeat();
            }
            let overrun = self.timer.sr().read().uif().bit_is_set();
            if overrun {
                st.overruns.fetch_add(1, Ordering::Relaxed);
            }
            if overrun
                || out.firmware_flags & (report::FW_SENSOR_ERROR | report::FW_SAMPLE_INVALID) != 0
            {
                self.leds.fault();
            }
            st.sensor_errors
                .store(self.counters.sensor_errors, Ordering::Relaxed);
            st.invalid_samples
                .store(self.counters.invalid_samples, Ordering::Relaxed);
            st.force_bits
                .store(out.estimate.force_n.to_bits(), Ordering::Relaxed);
            let cycles = DWT::cycle_count().wrapping_sub(start);
            self.worst = self.worst.max(cycles);
            st.last_step_cycles.store(cycles, Ordering::Relaxed);
            st.worst_step_cycles.store(self.worst, Ordering::Relaxed);
            st.steps.store(steps, Ordering::Release);
            self.leds.step(false);
        }
    }

    /// Writes the counters as a line starting with `what`.
    fn counters(console: &mut Console, what: &str) {
        let st: &Status = &NEMM_STATUS;
        let mut l = Line::new();
        l.str(what)
            .kv("steps", st.steps.load(Ordering::Acquire))
            .kv(
                "worst_step_cycles",
                st.worst_step_cycles.load(Ordering::Relaxed),
            )
            .kv(
                "last_step_cycles",
                st.last_step_cycles.load(Ordering::Relaxed),
            )
            .kv("budget_cycles", PERIOD_CYCLES)
            .kv("overruns", st.overruns.load(Ordering::Relaxed))
            .kv("sensor_errors", st.sensor_errors.load(Ordering::Relaxed))
            .kv(
                "invalid_samples",
                st.invalid_samples.load(Ordering::Relaxed),
            )
            .kx("force", st.force_bits.load(Ordering::Relaxed))
            .kv("console_dropped", console.dropped())
            .kv("stack_used", nemm_firmware::stack_used());
        console.write(l.finish());
    }

    /// The logger: a `status` line per second; in QEMU the summary and the exit.
    #[idle(local = [console])]
    fn idle(cx: idle::Context) -> ! {
        let console = cx.local.console;
        let mut next = STATUS_STEPS;
        loop {
            let steps = NEMM_STATUS.steps.load(Ordering::Acquire);
            if steps >= next {
                next = steps - steps % STATUS_STEPS + STATUS_STEPS;
                counters(console, "status");
            }
            #[cfg(feature = "qemu")]
            if steps >= crate::QEMU_RUN_STEPS {
                counters(console, "summary");
                cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
            }
            cortex_m::asm::wfi();
        }
    }
}
