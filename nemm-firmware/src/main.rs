//! The 10 kHz force estimator (RTIC 2).
//!
//! | context | priority | job |
//! |---------|----------|-----|
//! | `init` | - | boot report, options, weights validation, estimator construction, SysTick at 10 kHz |
//! | `sample` (SysTick) | 2 | read the stroke sensor, step the estimator, publish the force (bench-controller mode: read the load cell, step the alpha observer, publish its estimate), digest the result, queue a log record, detect overruns |
//! | `idle` | 0 | drain the log queue to the console; in QEMU, end the run after the recording |
//!
//! The only link between the two tasks is a lock-free single-producer single-consumer queue
//! (`heapless::spsc`): the 10 kHz task never waits for the logger. A full queue drops the
//! record and marks the next one ([`report::FW_LOG_GAP`]). The per-chunk digests of the
//! results do not go through the queue: the 10 kHz task stores them in a table the logger
//! prints after the run, so they are complete whatever the logger managed to print.
//!
//! Faults never stop the loop: a failed or invalid sensor read is counted, flagged, and the
//! estimator is fed NaN, on which it holds its last good input (and flags that too); a
//! period overrun (the next SysTick already pending when the step ends) is counted and flagged.
//! Bad weights are reported with their typed error and the estimator is not started.
//!
//! **Bench-controller mode** (`observer=on`, or the `observer` feature): each period also
//! reads the load cell (`nemm_firmware::loadcell`, a second SPI device) and steps the alpha
//! observer ([`nemm_firmware::FwObserver`], in a static) with the same velocity and position
//! as the estimator and the measured force; the estimate is published beside the force and
//! logged in the `s` line. A load-cell fault gives the observer NaN, which it skips. The
//! observer is built from the same decoded model; if it cannot be, the `observer-error` line
//! says why and the estimator runs alone. In exact mode the observer takes about seven model
//! steps per sample: more than the 100 us period of a 168 MHz Cortex-M4F (each period then
//! overruns, counted and flagged); under QEMU a slow `period_ticks=` replays without.
#![no_std]
#![no_main]

use nemm_firmware as _;

#[rtic::app(device = nemm_firmware::board::device, peripherals = false)]
mod app {
    use core::sync::atomic::{AtomicU32, Ordering};
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m::peripheral::SYST;
    use heapless::spsc::{Consumer, Producer, Queue};
    use nemm_core::{decode_into, DecodeError, EstimatorConfig, Model, StoredTables};
    use nemm_firmware::board::{
        self, Console, LoadCellSensor, Sensor, ALPHA_OUTPUT, FORCE_OUTPUT, PERIOD_TICKS,
    };
    use nemm_firmware::options::Options;
    use nemm_firmware::pipeline::{
        self, ChunkDigest, LoadCellCounters, SensorCounters, DIGEST_CHUNK_STEPS,
    };
    use nemm_firmware::report::{self, Line, ObserverRecord, StepRecord};
    use nemm_firmware::trace::Trace;
    use nemm_firmware::{slot, FwLevels, FwObserver, StaticSlot, PARAM_CAPACITY, SAMPLE_RATE_HZ};

    /// Log queue length (one slot stays free): 25.5 ms of records at 10 kHz.
    const LOG_QUEUE: usize = 256;
    /// Digest chunks kept (128 x 1000 periods: longer than any trace that fits the flash).
    const MAX_CHUNKS: usize = 128;

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
        sensor: SensorCounters,
        held: u32,
        resets: u32,
        overruns: u32,
        dropped: u32,
        max_step_ticks: u32,
        chunks: u32,
        /// Whether the observer ran (bench-controller mode).
        observer: bool,
        load_cell: LoadCellCounters,
    }

    /// The bench-controller mode's part of the 10 kHz task: the load cell and the observer.
    pub struct Bench {
        load_cell: LoadCellSensor,
        observer: &'static mut FwObserver,
    }

    /// Everything the 10 kHz task owns.
    pub struct SampleLoop {
        sensor: Sensor,
        estimator: &'static mut nemm_firmware::FwEstimator,
        bench: Option<Bench>,
        log: Producer<'static, LogItem>,
        syst: SYST,
        period_ticks: u32,
        options: Options,
        digest: ChunkDigest,
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

    /// What `build_estimator` gives: the estimator, the model, and the blob's tables index
    /// with the blob (the observer reads its level tables from them).
    type Built = (
        &'static mut nemm_firmware::FwEstimator,
        &'static Model<PARAM_CAPACITY>,
        (StoredTables, &'static [u8]),
    );

    /// The decoded model (kept: the estimator is built from it).
    static MODEL: StaticSlot<Model<PARAM_CAPACITY>> = StaticSlot::new();
    /// The estimator, lent to the 10 kHz task.
    static ESTIMATOR: StaticSlot<nemm_firmware::FwEstimator> = StaticSlot::new();
    /// The alpha observer (bench-controller mode), lent to the 10 kHz task.
    static OBSERVER: StaticSlot<FwObserver> = StaticSlot::new();
    /// The level tables the observer steps on (read from the blob at boot).
    static LEVELS: StaticSlot<FwLevels> = StaticSlot::new();
    /// The log queue between the 10 kHz task and the logger.
    static LOG: StaticSlot<Queue<LogItem, LOG_QUEUE>> = StaticSlot::new();
    /// CRC-32 of each chunk of [`DIGEST_CHUNK_STEPS`] periods, written by the 10 kHz task;
    /// the logger reads them after it received [`LogItem::Done`] (the queue orders the two).
    static CHUNK_DIGESTS: [AtomicU32; MAX_CHUNKS] = [const { AtomicU32::new(0) }; MAX_CHUNKS];

    /// Decodes and validates the weights into the model's static storage, in place: the one
    /// place the blob is decoded. Returns the model and the index of the blob's stored
    /// tables.
    fn load_model(
        blob: &[u8],
    ) -> Result<(&'static Model<PARAM_CAPACITY>, StoredTables), DecodeError> {
        let Some(model) = MODEL.init(Model::empty()) else {
            board::exit(report::EXIT_USAGE) // init runs once
        };
        let tables = decode_into(blob, model)?;
        Ok((model, tables))
    }

    #[init]
    fn init(_: init::Context) -> (Shared, Local) {
        board::init();
        let mut console = Console::open();
        let mut line = Line::new();
        line.str("boot")
            .ks("firmware", env!("CARGO_PKG_NAME"))
            .ks("version", env!("CARGO_PKG_VERSION"))
            .ks("board", board::NAME)
            .kv("capacity", PARAM_CAPACITY as u32);
        console.write(line.finish());
        let options = parse_options(&mut console);
        let period_ticks = options.period_ticks.unwrap_or(PERIOD_TICKS);
        let trace = open_trace(&mut console, &options);
        let mut sensor = board::sensor(trace);
        for w in &options.faults {
            // Both hold `MAX_FAULT_WINDOWS`.
            let _ = sensor.spi_mut().inject(*w);
        }
        let Some((estimator, model, stored)) =
            build_estimator(&mut console, &options, trace.oil_loss)
        else {
            let local = Local {
                sample_loop: None,
                logger: None,
                console,
            };
            return (Shared {}, local);
        };
        let bench = if nemm_firmware::OBSERVER_BUILT && options.observer_on() {
            build_observer(&mut console, model, &stored).map(|observer| {
                let mut load_cell = board::load_cell(trace);
                for w in &options.load_cell_faults {
                    // Both hold `MAX_FAULT_WINDOWS`.
                    let _ = load_cell.spi_mut().inject(*w);
                }
                Bench {
                    load_cell,
                    observer,
                }
            })
        } else {
            None
        };
        let Some(queue) = LOG.init(Queue::new()) else {
            board::exit(report::EXIT_USAGE)
        };
        let (log, logger) = queue.split();
        let bench_on = bench.is_some();
        start_line(&mut console, &options, period_ticks, &trace, bench_on);
        let syst = start_systick(period_ticks);
        (
            Shared {},
            Local {
                sample_loop: Some(SampleLoop {
                    sensor,
                    estimator,
                    bench,
                    log,
                    syst,
                    period_ticks,
                    options,
                    digest: ChunkDigest::new(),
                    counters: Summary {
                        observer: bench_on,
                        ..Summary::default()
                    },
                    log_gap: false,
                    done: false,
                }),
                logger: Some(logger),
                console,
            },
        )
    }

    /// The options from the command line (QEMU's, see `nemm_firmware::options`); an invalid
    /// one is reported and ends the run.
    fn parse_options(console: &mut Console) -> Options {
        let mut args = [0u8; board::ARGS_CAPACITY];
        match Options::parse(board::args(&mut args).unwrap_or("")) {
            Ok(o) => o,
            Err(bad) => {
                let mut l = Line::new();
                l.str("error").ks("kind", "bad-option").ks("option", bad);
                fail(console, &mut l, report::EXIT_USAGE)
            }
        }
    }

    /// The recorded trace the replay sensor serves (its first `samples=` only, if given);
    /// one at another sample rate, or none, is reported and ends the run.
    fn open_trace(console: &mut Console, options: &Options) -> Trace<'static> {
        match Trace::parse(board::trace_bytes()) {
            Ok(t) if t.sample_rate_hz == SAMPLE_RATE_HZ as f32 => match options.samples {
                Some(n) => t.prefix(n as usize),
                None => t,
            },
            _ => {
                let mut l = Line::new();
                l.str("error").ks("kind", "trace");
                fail(console, &mut l, report::EXIT_USAGE)
            }
        }
    }

    /// The estimator at level `alpha`, built in place in its static from the weights slot's
    /// blob (with the blob's stored tables at this level, if it has them: no table build at
    /// boot), and the `weights` line; with the decoded model. A missing or bad blob, a model
    /// of another rate or an estimator error is reported and gives `None`: the run goes on
    /// without an estimator.
    fn build_estimator(console: &mut Console, options: &Options, alpha: f32) -> Option<Built> {
        let blob = match slot::blob(board::weights_slot()) {
            Ok(b) => b,
            Err(e) => {
                let mut l = Line::new();
                report::slot_error(&mut l, &e);
                console.write(l.finish());
                return None;
            }
        };
        let (model, tables) = match load_model(blob) {
            Ok(loaded) => loaded,
            Err(e) => {
                let mut l = Line::new();
                report::decode_error(&mut l, &e);
                console.write(l.finish());
                return None;
            }
        };
        let mut l = Line::new();
        if !report::check_rate(&mut l, model.dt_s) {
            console.write(l.finish());
            return None;
        }
        let table = options.table.unwrap_or(nemm_firmware::TABLE_MODE_DEFAULT);
        let cfg = EstimatorConfig {
            mode: nemm_firmware::eval_mode(table),
            ..EstimatorConfig::new(alpha)
        };
        // Built in place in its static: nothing of the estimator's size is on the stack.
        let Some(estimator) = ESTIMATOR.init(nemm_firmware::FwEstimator::empty()) else {
            board::exit(report::EXIT_USAGE) // init runs once
        };
        if let Err(e) = estimator.load_with_tables(model, cfg, &tables, blob) {
            let mut l = Line::new();
            report::estimator_error(&mut l, &e);
            console.write(l.finish());
            return None;
        }
        let mut l = Line::new();
        report::weights_ok(&mut l, model, blob.len(), estimator);
        console.write(l.finish());
        Some((estimator, model, (tables, blob)))
    }

    /// The alpha observer of `model`, built in place in its static, and the `observer ok`
    /// line; an observer error is reported (`observer-error`) and gives `None`: the
    /// estimator runs without it.
    fn build_observer(
        console: &mut Console,
        model: &Model<PARAM_CAPACITY>,
        (tables, blob): &(StoredTables, &'static [u8]),
    ) -> Option<&'static mut FwObserver> {
        // Built in place in its static: nothing of the observer's size is on the stack.
        // The empty observer as one constant: copied from flash into the static, not built
        // on the stack first.
        const EMPTY: FwObserver = FwObserver::empty();
        const NO_LEVELS: FwLevels = FwLevels::empty();
        let (Some(observer), Some(levels)) =
            (OBSERVER.init_with(|| EMPTY), LEVELS.init_with(|| NO_LEVELS))
        else {
            board::exit(report::EXIT_USAGE) // init runs once
        };
        let mut l = Line::new();
        match observer.load(levels, model, tables, blob) {
            Ok(()) => {
                report::observer_ok(&mut l, observer);
                console.write(l.finish());
                Some(observer)
            }
            Err(e) => {
                report::observer_error(&mut l, &e);
                console.write(l.finish());
                None
            }
        }
    }

    /// The `start` line: the period, the trace, the injected faults and stalls, whether the
    /// observer runs, and the boot figures from reset to here (the estimator is ready; the
    /// first step runs one period after the SysTick set-up).
    fn start_line(
        console: &mut Console,
        options: &Options,
        period_ticks: u32,
        trace: &Trace<'_>,
        observer: bool,
    ) {
        let boot_ticks = board::boot_ticks();
        let mut l = Line::new();
        l.str("start")
            .kv("period_ticks", period_ticks)
            .kv("core_hz", board::SYSTICK_HZ)
            .kv("samples", trace.len() as u32)
            .kx("alpha", trace.oil_loss.to_bits())
            .kv("faults", options.faults.len() as u32)
            .kv("stalls", options.stalls.len() as u32)
            .ks("observer", if observer { "on" } else { "off" })
            .kv("boot_stack", board::stack_used());
        match boot_ticks {
            Some(t) => l.kv("boot_ticks", t),
            None => l.ks("boot_ticks", "wrapped"),
        };
        console.write(l.finish());
    }

    /// SysTick at `period_ticks` core-clock ticks per period, its interrupt (the 10 kHz task)
    /// enabled.
    fn start_systick(period_ticks: u32) -> SYST {
        // SAFETY: init runs once with interrupts disabled; the SysTick registers are owned by
        // this application (RTIC's `peripherals = false` leaves them to us).
        let mut syst = unsafe { cortex_m::Peripherals::steal() }.SYST;
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(period_ticks - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
        syst
    }

    /// The 10 kHz task.
    #[task(binds = SysTick, priority = 2, local = [sample_loop])]
    fn sample(cx: sample::Context) {
        if let Some(s) = cx.local.sample_loop {
            s.period();
        }
    }

    /// Busy-waits until SysTick has counted more than one whole period (without touching
    /// its COUNTFLAG, which the overrun detection reads): the `stall=` option.
    fn stall_one_period(period_ticks: u32) {
        let mut prev = SYST::get_current();
        let mut elapsed = 0u32;
        while elapsed <= period_ticks {
            let now = SYST::get_current();
            // Counting down from `period_ticks - 1`; a reload makes the value jump up.
            elapsed += if now <= prev {
                prev - now
            } else {
                prev + period_ticks - now
            };
            prev = now;
        }
    }

    impl SampleLoop {
        /// Queues `item` for the logger; `false` if the queue is full.
        #[inline(always)]
        fn log(&mut self, item: LogItem) -> bool {
            // heapless 0.9's queue halves compute their indices `% capacity` with the capacity
            // read at run time, which links a division-by-zero panic into this task. The
            // capacity is the constant `LOG_QUEUE - 1`; saying so lets the compiler fold the
            // division and drop the panic branch (tests/tests/qemu_no_panic.rs checks).
            self.log.capacity() == LOG_QUEUE - 1 && self.log.enqueue(item).is_ok()
        }

        /// Stores the CRC of the current digest chunk.
        fn close_chunk(&mut self) {
            let steps = self.digest.steps();
            let crc = self.digest.finish();
            if steps > 0 {
                if let Some(slot) = CHUNK_DIGESTS.get(self.counters.chunks as usize) {
                    slot.store(crc, Ordering::Relaxed);
                }
                self.counters.chunks += 1;
            }
        }

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
                self.close_chunk();
                let d = self.estimator.diagnostics();
                self.counters.held = d.held_samples;
                self.counters.resets = d.resets;
                if self.log(LogItem::Done(self.counters)) {
                    self.done = true;
                    self.syst.disable_counter();
                }
                return;
            }
            let k = self.counters.steps;
            if self.options.stalls_at(k) {
                stall_one_period(self.period_ticks);
            }
            let out =
                pipeline::run_period(&mut self.sensor, self.estimator, &mut self.counters.sensor);
            FORCE_OUTPUT.publish(out.estimate.force_n);
            self.digest.push(&out);
            // `OBSERVER_BUILT` false: `bench` is always `None`, and saying so leaves the
            // observer out of the image.
            let bench = self
                .bench
                .as_mut()
                .filter(|_| nemm_firmware::OBSERVER_BUILT);
            let observed = bench.map(|b| {
                let o = pipeline::observe_period(
                    &mut b.load_cell,
                    b.observer,
                    &out,
                    self.sensor.position_m(),
                    &mut self.counters.load_cell,
                );
                ALPHA_OUTPUT.publish(&o.estimate);
                self.digest.push_observed(&o);
                o
            });
            self.counters.steps += 1;
            if self.digest.steps() >= DIGEST_CHUNK_STEPS {
                self.close_chunk();
            }

            // Overrun: the counter wrapped (the next period started) during the step.
            let c = &mut self.counters;
            let mut fw = out.firmware_flags;
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
                velocity_m_s: out.velocity_m_s,
                force_n: out.estimate.force_n,
                estimator_flags: out.estimate.flags.0,
                firmware_flags: fw,
                ticks: ticks.min(u32::from(u16::MAX)) as u16,
                observer: observed.as_ref().map(ObserverRecord::from),
            };
            self.log_gap = !self.log(LogItem::Step(rec));
            if self.log_gap {
                self.counters.dropped += 1;
            }
        }
    }

    /// The end of the run: digests, counters, exit.
    fn report_run(console: &mut Console, s: &Summary) -> ! {
        let kept = (s.chunks as usize).min(MAX_CHUNKS);
        let crc = |c: usize| {
            CHUNK_DIGESTS
                .get(c)
                .map_or(0, |d| d.load(Ordering::Relaxed))
        };
        for c in 0..kept {
            let first = c as u32 * DIGEST_CHUNK_STEPS;
            let steps = s.steps.saturating_sub(first).min(DIGEST_CHUNK_STEPS);
            let mut l = Line::new();
            report::digest(&mut l, c as u32, first, steps, crc(c));
            console.write(l.finish());
        }
        let mut l = Line::new();
        l.str("summary")
            .kv("steps", s.steps)
            .kv("sensor_errors", s.sensor.sensor_errors)
            .kv("invalid_samples", s.sensor.invalid_samples)
            .kv("priming", s.sensor.priming)
            .kv("held", s.held)
            .kv("resets", s.resets)
            .kv("overruns", s.overruns)
            .kv("dropped", s.dropped)
            .kv("max_step_ticks", s.max_step_ticks)
            .kv("chunks", s.chunks)
            .kx("digest", pipeline::run_digest((0..kept).map(crc)))
            .kv("stack_used", board::stack_used());
        console.write(l.finish());
        if s.observer {
            let mut l = Line::new();
            l.str("load-cell")
                .kv("errors", s.load_cell.errors)
                .kv("invalid", s.load_cell.invalid)
                .kv("saturated", s.load_cell.saturated);
            console.write(l.finish());
        }
        let (force, published) = FORCE_OUTPUT.latest();
        let mut l = Line::new();
        l.str("exit")
            .kv("code", report::EXIT_DONE)
            .kv("published", published)
            .kx("last_force", force.to_bits());
        if s.observer {
            let (alpha, band, flags, n) = ALPHA_OUTPUT.latest();
            l.kv("alpha_published", n)
                .kx("last_alpha", alpha.to_bits())
                .kx("last_band", band.to_bits())
                .key("last_alpha_flags")
                .str("0x")
                .hex_bare(u32::from(flags), 2);
        }
        console.write(l.finish());
        board::exit(report::EXIT_DONE)
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
            // See `SampleLoop::log` for the capacity check.
            while logger.capacity() == LOG_QUEUE - 1 {
                let Some(item) = logger.dequeue() else { break };
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
                report_run(console, &s)
            }
            cortex_m::asm::wfi();
        }
    }
}
