//! The 10 kHz force estimator (RTIC 2).
//!
//! | context | priority | job |
//! |---------|----------|-----|
//! | `init` | - | boot report, weights validation, estimator construction, SysTick at 10 kHz |
//! | `sample` (SysTick) | 2 | read the stroke sensor, step the estimator, publish the force, queue a log record, detect overruns |
//! | `idle` | 0 | drain the log queue to the console; in QEMU, end the run after the recording |
//!
//! The only link between the two tasks is a lock-free single-producer single-consumer queue
//! (`heapless::spsc`): the 10 kHz task never waits for the logger. A full queue drops the
//! record and marks the next one ([`report::FW_LOG_GAP`]).
//!
//! Faults never stop the loop: a failed or invalid sensor read is counted, flagged, and the
//! estimator is fed NaN, on which it holds its last good input (and flags that too); a
//! period overrun (the next SysTick already pending when the step ends) is counted and flagged.
//! Bad weights are reported with their typed error and the estimator is not started.
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

use nemm_firmware as _;

#[rtic::app(device = nemm_firmware::board::device, peripherals = false)]
mod app {
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m::peripheral::SYST;
    use heapless::spsc::{Consumer, Producer, Queue};
    use nemm_core::{decode, Estimator, EstimatorConfig, Model};
    use nemm_firmware::board::{self, Console, Sensor, FORCE_OUTPUT, PERIOD_TICKS};
    use nemm_firmware::replay::FaultWindow;
    use nemm_firmware::report::{self, Line, StepRecord};
    use nemm_firmware::sensor::SensorError;
    use nemm_firmware::trace::Trace;
    use nemm_firmware::{slot, StaticSlot, PARAM_CAPACITY, SAMPLE_RATE_HZ};

    /// Log queue length (one slot stays free): 25.6 ms of records at 10 kHz.
    const LOG_QUEUE: usize = 257;

    /// What the 10 kHz task hands to the logger.
    pub enum LogItem {
        /// One period.
        Step(StepRecord),
        /// The recording ended; the run's counters.
        Done(Summary),
    }

    /// Counters of the run.
    #[derive(Clone, Copy, Default)]
    pub struct Summary {
        steps: u32,
        sensor_errors: u32,
        invalid_samples: u32,
        priming: u32,
        held: u32,
        resets: u32,
        overruns: u32,
        dropped: u32,
        max_step_ticks: u32,
    }

    /// Everything the 10 kHz task owns.
    pub struct SampleLoop {
        sensor: Sensor,
        estimator: &'static mut Estimator<PARAM_CAPACITY>,
        log: Producer<'static, LogItem>,
        syst: SYST,
        period_ticks: u32,
        counters: Summary,
        log_gap: bool,
        done: bool,
    }

    /// Writes `line` and ends the run with `code`.
    fn fail(console: &mut Console, line: &mut Line, code: u32) -> ! {
        console.write(line.finish());
        board::exit(code)
    }

    #[shared]
    struct Shared {}

    #[local]
    struct Local {
        sample_loop: Option<SampleLoop>,
        logger: Option<Consumer<'static, LogItem>>,
        console: Console,
    }

    /// The decoded model (kept: the estimator is built from it).
    static MODEL: StaticSlot<Model<PARAM_CAPACITY>> = StaticSlot::new();
    /// The estimator, lent to the 10 kHz task.
    static ESTIMATOR: StaticSlot<Estimator<PARAM_CAPACITY>> = StaticSlot::new();
    /// The log queue between the 10 kHz task and the logger.
    static LOG: StaticSlot<Queue<LogItem, LOG_QUEUE>> = StaticSlot::new();

    #[init]
    fn init(_: init::Context) -> (Shared, Local) {
        let mut console = Console::open();
        let mut line = Line::new();
        line.str("boot")
            .ks("firmware", env!("CARGO_PKG_NAME"))
            .ks("version", env!("CARGO_PKG_VERSION"))
            .ks("board", board::NAME)
            .kv("capacity", PARAM_CAPACITY as u32);
        console.write(line.finish());

        let trace = match Trace::parse(board::trace_bytes()) {
            Ok(t) if t.sample_rate_hz == SAMPLE_RATE_HZ as f32 => t,
            _ => {
                let mut l = Line::new();
                l.str("error").ks("kind", "trace");
                fail(&mut console, &mut l, report::EXIT_USAGE)
            }
        };
        let mut sensor = board::sensor(trace);

        // Options (QEMU command line): `fault=bus@START+LEN`, `fault=nan@START+LEN`,
        // `period_ticks=N` (sample period in SysTick ticks, default 10 kHz).
        let mut args = [0u8; board::ARGS_CAPACITY];
        let mut n_faults = 0u32;
        let mut period_ticks = PERIOD_TICKS;
        for arg in board::args(&mut args)
            .unwrap_or("")
            .split_ascii_whitespace()
        {
            let ok = if let Some(w) = arg.strip_prefix("fault=") {
                match FaultWindow::parse(w) {
                    Some(w) if sensor.spi_mut().inject(w) => {
                        n_faults += 1;
                        true
                    }
                    _ => false,
                }
            } else if let Some(n) = arg.strip_prefix("period_ticks=") {
                match n.parse::<u32>() {
                    Ok(n) if (100..=0xFF_FFFF).contains(&n) => {
                        period_ticks = n;
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

        let no_estimator = |console: Console| Local {
            sample_loop: None,
            logger: None,
            console,
        };
        let blob = match slot::blob(board::weights_slot()) {
            Ok(b) => b,
            Err(e) => {
                let mut l = Line::new();
                report::slot_error(&mut l, &e);
                console.write(l.finish());
                return (Shared {}, no_estimator(console));
            }
        };
        let model: &'static Model<PARAM_CAPACITY> = match decode(blob) {
            Ok(m) => match MODEL.init(m) {
                Some(m) => m,
                None => board::exit(report::EXIT_USAGE),
            },
            Err(e) => {
                let mut l = Line::new();
                report::decode_error(&mut l, &e);
                console.write(l.finish());
                return (Shared {}, no_estimator(console));
            }
        };
        let period_s = 1.0 / SAMPLE_RATE_HZ as f32;
        if (model.dt_s - period_s).abs() > 1e-3 * period_s {
            let mut l = Line::new();
            l.str("weights-error")
                .ks("source", "firmware")
                .ks("kind", "rate-mismatch")
                .kx("dt_s", model.dt_s.to_bits());
            console.write(l.finish());
            return (Shared {}, no_estimator(console));
        }
        let estimator = match Estimator::new(model, EstimatorConfig::new(trace.oil_loss)) {
            Ok(e) => match ESTIMATOR.init(e) {
                Some(e) => e,
                None => board::exit(report::EXIT_USAGE),
            },
            Err(e) => {
                let mut l = Line::new();
                report::estimator_error(&mut l, &e);
                console.write(l.finish());
                return (Shared {}, no_estimator(console));
            }
        };
        let mut l = Line::new();
        l.str("weights ok")
            .ks("kind", model.kind().name())
            .kv("bytes", blob.len() as u32)
            .ks("integrator", model.integrator.name())
            .kv("dt_ns", (model.dt_s * 1e9 + 0.5) as u32);
        console.write(l.finish());

        let Some(queue) = LOG.init(Queue::new()) else {
            board::exit(report::EXIT_USAGE)
        };
        let (log, logger) = queue.split();
        let mut l = Line::new();
        l.str("start")
            .kv("period_ticks", period_ticks)
            .kv("core_hz", board::SYSTICK_HZ)
            .kv("samples", trace.len() as u32)
            .kx("alpha", trace.oil_loss.to_bits())
            .kv("faults", n_faults);
        console.write(l.finish());

        // SAFETY: init runs once with interrupts disabled; the SysTick registers are owned by
        // this application (RTIC's `peripherals = false` leaves them to us).
        let mut syst = unsafe { cortex_m::Peripherals::steal() }.SYST;
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(period_ticks - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();

        (
            Shared {},
            Local {
                sample_loop: Some(SampleLoop {
                    sensor,
                    estimator,
                    log,
                    syst,
                    period_ticks,
                    counters: Summary::default(),
                    log_gap: false,
                    done: false,
                }),
                logger: Some(logger),
                console,
            },
        )
    }

    /// The 10 kHz task.
    #[task(binds = SysTick, priority = 2, local = [sample_loop])]
    fn sample(cx: sample::Context) {
        if let Some(s) = cx.local.sample_loop {
            s.period();
        }
    }

    impl SampleLoop {
        #[inline(always)]
        fn period(&mut self) {
            // Reading the control register clears COUNTFLAG, set by the wrap that started
            // this period; if it is set again at the end, the step overran the period.
            let _ = self.syst.has_wrapped();
            if self.done {
                return;
            }
            if self.sensor.spi().finished() {
                // End of the recording (replay only): hand the counters to the logger and stop.
                let d = self.estimator.diagnostics();
                self.counters.held = d.held_samples;
                self.counters.resets = d.resets;
                if self.log.enqueue(LogItem::Done(self.counters)).is_ok() {
                    self.done = true;
                    self.syst.disable_counter();
                }
                return;
            }
            let k = self.counters.steps;
            let c = &mut self.counters;
            let (velocity, mut fw) = match self.sensor.read_velocity() {
                Ok(v) if v.is_finite() => (v, 0),
                Ok(_) | Err(SensorError::Invalid) => {
                    c.invalid_samples += 1;
                    (f32::NAN, report::FW_SAMPLE_INVALID)
                }
                Err(SensorError::Priming) => {
                    c.priming += 1;
                    (f32::NAN, report::FW_PRIMING)
                }
                Err(SensorError::Bus(_) | SensorError::NotReady) => {
                    c.sensor_errors += 1;
                    (f32::NAN, report::FW_SENSOR_ERROR)
                }
            };
            // NaN in: the estimator holds its last good input and flags the step.
            let e = self.estimator.step(velocity);
            FORCE_OUTPUT.publish(e.force_n);
            c.steps += 1;

            // Overrun: the counter wrapped (the next period started) during the step.
            let ticks = if self.syst.has_wrapped() {
                c.overruns += 1;
                fw |= report::FW_OVERRUN;
                0
            } else {
                let t = self.period_ticks - 1 - SYST::get_current();
                c.max_step_ticks = c.max_step_ticks.max(t);
                t
            };
            if self.log_gap {
                fw |= report::FW_LOG_GAP;
            }
            let rec = StepRecord {
                k,
                velocity_m_s: velocity,
                force_n: e.force_n,
                estimator_flags: e.flags.0,
                firmware_flags: fw,
                ticks: ticks.min(u32::from(u16::MAX)) as u16,
            };
            self.log_gap = self.log.enqueue(LogItem::Step(rec)).is_err();
            if self.log_gap {
                c.dropped += 1;
            }
        }
    }

    /// The logger: lowest priority, drains the queue in console-sized chunks.
    #[idle(local = [logger, console])]
    fn idle(cx: idle::Context) -> ! {
        let console = cx.local.console;
        let Some(logger) = cx.local.logger else {
            // Bad weights: the estimator was never started.
            board::exit(report::EXIT_BAD_WEIGHTS)
        };
        let mut chunk = heapless::Vec::<u8, 2048>::new();
        loop {
            let mut done = None;
            while let Some(item) = logger.dequeue() {
                let mut line = Line::new();
                match item {
                    LogItem::Step(r) => r.write(&mut line),
                    LogItem::Done(s) => {
                        done = Some(s);
                        break;
                    }
                }
                let bytes = line.finish();
                if chunk.len() + bytes.len() > chunk.capacity() {
                    console.write(&chunk);
                    chunk.clear();
                }
                let _ = chunk.extend_from_slice(bytes);
            }
            console.write(&chunk);
            chunk.clear();
            if let Some(s) = done {
                let mut l = Line::new();
                l.str("summary")
                    .kv("steps", s.steps)
                    .kv("sensor_errors", s.sensor_errors)
                    .kv("invalid_samples", s.invalid_samples)
                    .kv("priming", s.priming)
                    .kv("held", s.held)
                    .kv("resets", s.resets)
                    .kv("overruns", s.overruns)
                    .kv("dropped", s.dropped)
                    .kv("max_step_ticks", s.max_step_ticks)
                    .kv("stack_used", board::stack_used());
                console.write(l.finish());
                let (force, published) = FORCE_OUTPUT.latest();
                let mut l = Line::new();
                l.str("exit")
                    .kv("code", report::EXIT_DONE)
                    .kv("published", published)
                    .kx("last_force", force.to_bits());
                console.write(l.finish());
                board::exit(report::EXIT_DONE)
            }
            cortex_m::asm::wfi();
        }
    }
}
