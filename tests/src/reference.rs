//! The host reference of a firmware run: the firmware's own sample path
//! (`nemm_firmware::pipeline::run_period`: the `StrokeSensor` driver on the replay ADC, then
//! `nemm_core::Estimator::step`) compiled for the host, over the recording and the weights
//! taken from the firmware image, with the same options (the evaluation mode included).

use nemm_core::{decode, Diagnostics, EstimatorConfig, Model};
use nemm_firmware::options::Options;
use nemm_firmware::pipeline::{self, ChunkDigest, PeriodOutput, SensorCounters};
use nemm_firmware::replay::ReplayAdc;
use nemm_firmware::sensor::StrokeSensor;
use nemm_firmware::trace::Trace;
use nemm_firmware::{
    eval_mode, stroke_calibration, FwEstimator, PARAM_CAPACITY, TABLE_MODE_DEFAULT,
};

/// What the host computed.
#[derive(Debug, Clone)]
pub struct Reference {
    /// One output per period.
    pub outputs: Vec<PeriodOutput>,
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
/// path with the weights `blob` and the run `options` (faults, `samples=`).
pub fn run(trace: &[u8], blob: &[u8], options: &Options) -> Reference {
    let trace = Trace::parse(trace).expect("the firmware's trace parses");
    let trace = match options.samples {
        Some(n) => trace.prefix(n as usize),
        None => trace,
    };
    let model: Model<PARAM_CAPACITY> = decode(blob).expect("the weights decode on the host");
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
    let mut outputs = Vec::with_capacity(trace.len());
    let mut chunk_digests = Vec::new();
    let mut digest = ChunkDigest::new();
    while !sensor.spi().finished() {
        let out = pipeline::run_period(&mut sensor, &mut estimator, &mut counters);
        digest.push(&out);
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
        counters,
        diagnostics: estimator.diagnostics(),
        run_digest: pipeline::run_digest(chunk_digests.iter().copied()),
        chunk_digests,
    }
}
