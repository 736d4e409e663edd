//! The host reference of a firmware run: the firmware's own sample path
//! (`nemm_firmware::pipeline::run_period`: the `StrokeSensor` driver on the replay ADC, then
//! `nemm_core::Estimator::step`) compiled for the host, over the recording and the weights
//! taken from the firmware image, with the same options (the evaluation mode included).
//! With the observer (`observer=on`), also the bench-controller part
//! (`nemm_firmware::pipeline::observe_period`: the `LoadCell` driver on the replay load
//! cell, then `nemm_core::AlphaObserver`, the firmware's `FwObserver`).

use nemm_core::{Diagnostics, EstimatorConfig, Model};
use nemm_firmware::loadcell::LoadCell;
use nemm_firmware::options::Options;
use nemm_firmware::pipeline::{
    self, ChunkDigest, LoadCellCounters, ObservedOutput, PeriodOutput, SensorCounters,
};
use nemm_firmware::replay::{ReplayAdc, ReplayLoadCell};
use nemm_firmware::sensor::StrokeSensor;
use nemm_firmware::trace::Trace;
use nemm_firmware::{
    eval_mode, load_cell_calibration, stroke_calibration, FwEstimator, FwObserver, PARAM_CAPACITY,
    TABLE_MODE_DEFAULT,
};

/// What the host computed.
#[derive(Debug, Clone)]
pub struct Reference {
    /// One output per period.
    pub outputs: Vec<PeriodOutput>,
    /// The observer's output per period (empty without the observer).
    pub observed: Vec<ObservedOutput>,
    /// Load-cell fault counters at the end (zero without the observer).
    pub load_cell: LoadCellCounters,
    /// Sensor fault counters at the end.
    pub counters: SensorCounters,
    /// The estimator's counters at the end.
    pub diagnostics: Diagnostics,
    /// CRC-32 per chunk of `pipeline::DIGEST_CHUNK_STEPS` periods.
    pub chunk_digests: Vec<u32>,
    /// CRC-32 over the chunk CRCs.
    pub run_digest: u32,
}

/// Runs the recording `trace` (the bytes of the firmware's `.nemm_trace`) through the sample
/// path with the weights `blob` and the run `options` (faults, `samples=`, the observer and
/// its load-cell faults).
pub fn run(trace: &[u8], blob: &[u8], options: &Options) -> Reference {
    let trace = Trace::parse(trace).expect("the firmware's trace parses");
    let trace = match options.samples {
        Some(n) => trace.prefix(n as usize),
        None => trace,
    };
    let (model, tables): (Model<PARAM_CAPACITY>, _) =
        nemm_core::decode_with_tables(blob).expect("the weights decode on the host");
    // The firmware's estimator type and evaluation mode (`mode=`, else the build's default).
    let config = EstimatorConfig {
        mode: eval_mode(options.table.unwrap_or(TABLE_MODE_DEFAULT)),
        ..EstimatorConfig::new(trace.oil_loss)
    };
    let mut estimator = Box::new(
        FwEstimator::with_segments(&model, config).expect("the estimator builds on the host"),
    );
    let cal = stroke_calibration();
    let mut adc = ReplayAdc::new(trace, cal);
    for w in &options.faults {
        assert!(adc.inject(*w));
    }
    let mut sensor = StrokeSensor::new(adc, cal);
    let mut counters = SensorCounters::default();
    // The bench-controller part, as the firmware builds it.
    let mut bench = options.observer_on().then(|| {
        let mut observer = Box::new(FwObserver::empty());
        // The firmware's level tables live in a `static` and read the weights slot in place:
        // here, leaked boxes, the blob held 4-byte aligned as the slot holds it.
        let levels = Box::leak(Box::new(nemm_firmware::FwLevels::empty()));
        let slot: &'static [u8] = Box::leak(Box::new(nemm_core::AlignedBlob::new(blob)));
        observer
            .load(levels, &model, &tables, slot)
            .expect("the observer builds on the host");
        let lc_cal = load_cell_calibration();
        let mut device = ReplayLoadCell::new(trace, lc_cal);
        for w in &options.load_cell_faults {
            assert!(device.inject(*w));
        }
        (LoadCell::new(device, lc_cal), observer)
    });
    let mut load_cell = LoadCellCounters::default();
    let mut observed = Vec::new();
    let mut outputs = Vec::with_capacity(trace.len());
    let mut chunk_digests = Vec::new();
    let mut digest = ChunkDigest::new();
    while !sensor.spi().finished() {
        let out = pipeline::run_period(&mut sensor, &mut estimator, &mut counters);
        digest.push(&out);
        if let Some((lc, observer)) = &mut bench {
            let o =
                pipeline::observe_period(lc, observer, &out, sensor.position_m(), &mut load_cell);
            digest.push_observed(&o);
            observed.push(o);
        }
        if digest.steps() == pipeline::DIGEST_CHUNK_STEPS {
            chunk_digests.push(digest.finish());
        }
        outputs.push(out);
    }
    if digest.steps() > 0 {
        chunk_digests.push(digest.finish());
    }
    Reference {
        outputs,
        observed,
        load_cell,
        counters,
        diagnostics: estimator.diagnostics(),
        run_digest: pipeline::run_digest(chunk_digests.iter().copied()),
        chunk_digests,
    }
}
