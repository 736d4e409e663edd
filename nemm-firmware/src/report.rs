//! The firmware's output: one ASCII line per event, `key=value` fields, parsed by the host
//! tests (`tests/src/firmware.rs`). Formatting is hand-written (decimal and hex integers,
//! `f32` as raw bits) so that no `core::fmt` machinery, and none of its panic paths, is
//! linked.
//!
//! ```text
//! boot firmware=nemm-firmware version=0.1.0 board=mps2-an386 capacity=1313
//! weights ok kind=nemm bytes=15791 integrator=rk4 dt_ns=100000
//! weights ok kind=nemm bytes=30231 integrator=rk4 dt_ns=100000 mode=table table_bytes=7168 table_max_rel_error_ppb=2792 tables=stored
//! weights-error source=decode kind=crc-mismatch stored=0x1234abcd computed=0x89abcdef
//! weights-error source=decode kind=invalid reason=non-finite field=b_fl.params
//! observer ok levels=7 alpha_lo=0x00000000 alpha_hi=0x3e99999a bytes=21696 model_steps=7
//! observer-error kind=estimator reason=table
//! start period_ticks=2500 core_hz=25000000 samples=10500 alpha=0x3e19999a faults=0 stalls=0 observer=off boot_stack=8208 boot_ticks=18000
//! s <k> <velocity f32 bits> <force f32 bits> <estimator flags> <firmware flags> <ticks>
//! s <k> <velocity> <force> <estimator flags> <firmware flags> <ticks> measured=0x44fe2666 alpha=0x3e19db23 band=0x3d1c28f6 flags=0x00
//! digest chunk=0 first=0 steps=1000 crc=0x1c2b3a49
//! summary steps=10500 sensor_errors=0 invalid_samples=0 priming=1 held=1 resets=0 overruns=0 dropped=0 max_step_ticks=412 chunks=11 digest=0x0badf00d stack_used=1864
//! load-cell errors=0 invalid=0 saturated=0
//! exit code=0 published=10500 last_force=0xc3a1a970
//! exit code=0 published=10500 last_force=0xc3a1a970 alpha_published=10500 last_alpha=0x3e19db23 last_band=0x3d1c28f6 last_alpha_flags=0x00
//! ```
//!
//! In `s` lines `k` and `ticks` are decimal, the rest hex; `velocity` is the value handed to
//! the estimator (NaN when the sensor path had none), `ticks` the SysTick ticks from the
//! start of the period to the end of the step (0 for an overrun). The firmware flags are
//! [`FW_SENSOR_ERROR`], [`FW_SAMPLE_INVALID`], [`FW_PRIMING`], [`FW_OVERRUN`],
//! [`FW_LOG_GAP`]. `s` lines can be dropped when the logger falls behind (the next record
//! then carries [`FW_LOG_GAP`]); `digest` lines never are: the 10 kHz task computes one
//! CRC-32 per chunk of periods ([`crate::pipeline::ChunkDigest`]) and the logger prints
//! them after the run, and `summary`'s `digest` is the CRC over those
//! ([`crate::pipeline::run_digest`]).
//!
//! With the alpha observer (`observer=on`, the bench-controller mode), `observer ok` (or
//! `observer-error`: the estimator runs on without the observer) follows `weights ok`, each
//! `s` line carries the observer's part as `key=value` fields ([`ObserverRecord`]): the load
//! cell's force handed to the observer, the estimate of alpha, its band (half-width) as `f32`
//! bits, and the observer's flags ([`nemm_core::ObserverFlags`]); a `load-cell` line after
//! the `summary` counts the load cell's faults (failed reads and "no new conversion",
//! invalid conversions, saturated ones) and `exit` adds the last published estimate.
//!
//! In table mode `weights ok` says where the tables came from: `tables=stored` (read from
//! the blob's tables section) or `tables=built stored_unused=<reason>` (built at boot; the
//! reason is [`nemm_core::StoredUnused::name`]). `boot_ticks` of `start` are the SysTick
//! ticks from reset to the estimator ready (`board::boot_ticks`; `wrapped` if
//! they exceed SysTick's 24-bit range).
//!
//! A `weights-error` line names the layer that refused the weights (`source=slot`,
//! `decode`, `firmware` or `estimator`) and the typed error as `kind=` plus its fields;
//! a model rejected by its checks adds the [`ModelError`] as `reason=` plus its fields.

use nemm_core::{
    DecodeError, Estimator, EstimatorError, Model, ModelError, ObserverError, TableError,
    TableOrigin,
};

use crate::slot::SlotError;

/// The SPI read failed or the ADC had no new conversion.
pub const FW_SENSOR_ERROR: u8 = 1 << 0;
/// The ADC flagged the conversion invalid, or the velocity was not finite.
pub const FW_SAMPLE_INVALID: u8 = 1 << 1;
/// The differentiator was re-priming after start-up or a fault.
pub const FW_PRIMING: u8 = 1 << 2;
/// This step ended after the next period had started.
pub const FW_OVERRUN: u8 = 1 << 3;
/// Log records before this one were dropped (the queue was full).
pub const FW_LOG_GAP: u8 = 1 << 4;

/// Exit code: the recording was replayed to its end.
pub const EXIT_DONE: u32 = 0;
/// Exit code: the weights were rejected, the estimator was not started.
pub const EXIT_BAD_WEIGHTS: u32 = 2;
/// Exit code: a hard fault (never expected).
pub const EXIT_HARD_FAULT: u32 = 3;
/// Exit code: a panic (never expected; the release build links no panic path).
pub const EXIT_PANIC: u32 = 4;
/// Exit code: bad command-line option or trace.
pub const EXIT_USAGE: u32 = 5;

/// Longest line.
pub const LINE_CAPACITY: usize = 200;

/// One output line under construction; silently truncates at [`LINE_CAPACITY`].
#[derive(Debug, Default, Clone)]
pub struct Line {
    buf: heapless::Vec<u8, LINE_CAPACITY>,
}

impl Line {
    /// An empty line.
    pub const fn new() -> Self {
        Self {
            buf: heapless::Vec::new(),
        }
    }

    /// Appends text.
    pub fn str(&mut self, s: &str) -> &mut Self {
        for &b in s.as_bytes() {
            if self.buf.push(b).is_err() {
                break;
            }
        }
        self
    }

    /// Appends ` key=`.
    pub fn key(&mut self, k: &str) -> &mut Self {
        self.str(" ").str(k).str("=")
    }

    /// Appends a decimal number.
    pub fn dec(&mut self, v: u32) -> &mut Self {
        let mut digits = [0u8; 10];
        let mut n = v;
        let mut i = digits.len();
        loop {
            i -= 1;
            if let Some(d) = digits.get_mut(i) {
                *d = b'0' + (n % 10) as u8;
            }
            n /= 10;
            if n == 0 || i == 0 {
                break;
            }
        }
        for &d in digits.get(i..).unwrap_or(&[]) {
            let _ = self.buf.push(d);
        }
        self
    }

    /// Appends `0x` and eight hex digits.
    pub fn hex(&mut self, v: u32) -> &mut Self {
        self.str("0x").hex_bare(v, 8)
    }

    /// Appends `digits` hex digits without prefix.
    pub fn hex_bare(&mut self, v: u32, digits: u32) -> &mut Self {
        for i in (0..digits.min(8)).rev() {
            let nib = ((v >> (4 * i)) & 0xF) as u8;
            let _ = self.buf.push(if nib < 10 {
                b'0' + nib
            } else {
                b'a' + nib - 10
            });
        }
        self
    }

    /// Appends ` key=<decimal>`.
    pub fn kv(&mut self, k: &str, v: u32) -> &mut Self {
        self.key(k).dec(v)
    }

    /// Appends ` key=0x<hex>`.
    pub fn kx(&mut self, k: &str, v: u32) -> &mut Self {
        self.key(k).hex(v)
    }

    /// Appends ` key=text`.
    pub fn ks(&mut self, k: &str, v: &str) -> &mut Self {
        self.key(k).str(v)
    }

    /// The line with its newline.
    pub fn finish(&mut self) -> &[u8] {
        if self.buf.is_full() {
            self.buf.pop();
        }
        let _ = self.buf.push(b'\n');
        &self.buf
    }

    /// The bytes so far.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf
    }
}

fn sat(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

/// ` reason=<kebab-case name>` of a model error and its fields.
pub fn model_error(line: &mut Line, e: &ModelError) {
    match e {
        ModelError::NonFinite { field } => line.ks("reason", "non-finite").ks("field", field),
        ModelError::NotPositive { field } => line.ks("reason", "not-positive").ks("field", field),
        ModelError::Negative { field } => line.ks("reason", "negative").ks("field", field),
        ModelError::StaticForceOnSem => line.ks("reason", "static-force-on-sem"),
        ModelError::LostMotionOnSem => line.ks("reason", "lost-motion-on-sem"),
        ModelError::OutOfRange { field } => line.ks("reason", "out-of-range").ks("field", field),
        ModelError::BadScalerBounds { scaler } => {
            line.ks("reason", "bad-scaler-bounds").ks("scaler", scaler)
        }
        ModelError::Shape { scaler, .. } => line.ks("reason", "shape").ks("scaler", scaler),
        ModelError::WrongInputCount {
            scaler,
            expected,
            found,
        } => line
            .ks("reason", "wrong-input-count")
            .ks("scaler", scaler)
            .kv("expected", u32::from(*expected))
            .kv("found", u32::from(*found)),
        ModelError::Sem(_) => line.ks("reason", "sem-map"),
        ModelError::AlphaRange => line.ks("reason", "alpha-range"),
        ModelError::ControlCharacter { field } => {
            line.ks("reason", "control-character").ks("field", field)
        }
        ModelError::UnstableStep { .. } => line.ks("reason", "unstable-step"),
        ModelError::Branch { scaler, .. } => line.ks("reason", "alpha-branch").ks("scaler", scaler),
        ModelError::Cumulative { scaler, .. } => {
            line.ks("reason", "cumulative-scaler").ks("scaler", scaler)
        }
        ModelError::Condition { field } => line.ks("reason", "condition").ks("field", field),
    };
}

/// `weights-error source=slot ...`.
pub fn slot_error(line: &mut Line, e: &SlotError) {
    line.str("weights-error").ks("source", "slot");
    match e {
        SlotError::Empty => line.ks("kind", "empty"),
        SlotError::BadMagic => line.ks("kind", "bad-magic"),
        SlotError::TooLong { len, capacity } => line
            .ks("kind", "too-long")
            .kv("len", *len)
            .kv("capacity", *capacity),
    };
}

/// `weights-error source=decode ...`: the typed [`DecodeError`] with its fields.
pub fn decode_error(line: &mut Line, e: &DecodeError) {
    line.str("weights-error").ks("source", "decode");
    match e {
        DecodeError::Truncated { needed, found } => line
            .ks("kind", "truncated")
            .kv("needed", sat(*needed))
            .kv("found", sat(*found)),
        DecodeError::BadMagic { found } => line
            .ks("kind", "bad-magic")
            .kx("found", u32::from_be_bytes(*found)),
        DecodeError::UnsupportedVersion { found, supported } => line
            .ks("kind", "unsupported-version")
            .kv("found", u32::from(*found))
            .kv("supported", u32::from(*supported)),
        DecodeError::TrailingBytes { extra } => {
            line.ks("kind", "trailing-bytes").kv("extra", sat(*extra))
        }
        DecodeError::CrcMismatch { stored, computed } => line
            .ks("kind", "crc-mismatch")
            .kx("stored", *stored)
            .kx("computed", *computed),
        DecodeError::OverCapacity { needed, capacity } => line
            .ks("kind", "over-capacity")
            .kv("needed", sat(*needed))
            .kv("capacity", sat(*capacity)),
        DecodeError::Malformed { part } => line.ks("kind", "malformed").ks("part", part),
        DecodeError::Invalid(m) => {
            line.ks("kind", "invalid");
            model_error(line, m);
            line
        }
    };
}

/// `weights-error source=estimator ...`.
pub fn estimator_error(line: &mut Line, e: &EstimatorError) {
    line.str("weights-error").ks("source", "estimator");
    estimator_error_fields(line, e);
}

/// ` kind=<name>` of an estimator error and its fields.
fn estimator_error_fields(line: &mut Line, e: &EstimatorError) {
    match e {
        EstimatorError::AlphaOutOfRange => line.ks("kind", "alpha-out-of-range"),
        EstimatorError::BadVelocityLimit => line.ks("kind", "bad-velocity-limit"),
        EstimatorError::Model(m) => {
            line.ks("kind", "model");
            model_error(line, m);
            line
        }
        EstimatorError::Compile => line.ks("kind", "compile"),
        EstimatorError::Table(t) => {
            line.ks("kind", "table");
            table_error(line, t);
            line
        }
        EstimatorError::AlphaPerSampleInTableMode => {
            line.ks("kind", "alpha-per-sample-in-table-mode")
        }
        EstimatorError::Levels(l) => line.ks("kind", "levels").ks("levels", l.name()),
    };
}

/// `observer-error kind=...`: why the observer could not be built (the estimator runs
/// without it). `kind=estimator` carries the estimator's error as `reason=` (its `kind`
/// name) and fields.
pub fn observer_error(line: &mut Line, e: &ObserverError) {
    line.str("observer-error");
    match e {
        ObserverError::Estimator(inner) => {
            line.ks("kind", "estimator");
            let mut fields = Line::new();
            estimator_error_fields(&mut fields, inner);
            // ` kind=x ...` of the estimator as ` reason=x ...`.
            let bytes = fields.as_bytes();
            let rest = bytes.strip_prefix(b" kind=").unwrap_or(bytes);
            line.str(" reason=");
            for &b in rest {
                if line.buf.push(b).is_err() {
                    break;
                }
            }
        }
        ObserverError::Grid => {
            line.ks("kind", "grid");
        }
        ObserverError::Points {
            requested,
            capacity,
        } => {
            line.ks("kind", "points")
                .kv("requested", sat(*requested))
                .kv("capacity", sat(*capacity));
        }
        ObserverError::Setting(name) => {
            line.ks("kind", "setting").ks("setting", name);
        }
    }
}

/// The `observer ok` line: the grid's levels, its lowest and highest level (`f32` bits), the
/// observer's RAM and the model steps it takes per sample.
pub fn observer_ok(line: &mut Line, fw: &crate::FwObserver) {
    let observer = fw.observer();
    let mut grid = observer.grid();
    let lo = grid.next().unwrap_or(f32::NAN);
    let hi = grid.last().unwrap_or(lo);
    line.str("observer ok")
        .kv("levels", sat(observer.points()))
        .kx("alpha_lo", lo.to_bits())
        .kx("alpha_hi", hi.to_bits())
        .kv("bytes", sat(core::mem::size_of::<crate::FwObserver>()))
        .kv("model_steps", sat(observer.evaluations_per_step()))
        .ks("levels_from", if fw.on_levels() { "blob" } else { "exact" })
        .kv(
            "level_table_bytes",
            sat(fw.levels().map_or(0, |l| l.table_bytes().1)),
        );
}

/// Whether a model stepping `dt_s` seconds runs at [`crate::SAMPLE_RATE_HZ`] (within
/// 0.1 %); if not, writes the `weights-error source=firmware kind=rate-mismatch` line.
pub fn check_rate(line: &mut Line, dt_s: f32) -> bool {
    let period_s = 1.0 / crate::SAMPLE_RATE_HZ as f32;
    if (dt_s - period_s).abs() > 1e-3 * period_s {
        line.str("weights-error")
            .ks("source", "firmware")
            .ks("kind", "rate-mismatch")
            .kx("dt_s", dt_s.to_bits());
        return false;
    }
    true
}

/// The `weights ok` line of a validated blob of `bytes` bytes and the estimator built from
/// it (in table mode with `table_bytes=` and `table_max_rel_error_ppb=`).
pub fn weights_ok<const P: usize, const T: usize>(
    line: &mut Line,
    model: &Model<P>,
    bytes: usize,
    estimator: &Estimator<P, T>,
) {
    line.str("weights ok")
        .ks("kind", model.kind().name())
        .kv("bytes", bytes as u32)
        .ks("integrator", model.integrator.name())
        .kv("dt_ns", (model.dt_s * 1e9 + 0.5) as u32)
        .ks("mode", estimator.mode().name());
    if let Some(acc) = estimator.table_accuracy() {
        line.kv("table_bytes", estimator.table_bytes().1 as u32)
            .kv("table_max_rel_error_ppb", ppb(acc.max_rel_error));
    }
    // Where the tables came from: the blob's tables section, or built at boot (and why the
    // blob's were not used).
    match estimator.table_origin() {
        TableOrigin::None => {}
        TableOrigin::Stored => {
            line.ks("tables", "stored");
        }
        TableOrigin::Built(why) => {
            line.ks("tables", "built").ks("stored_unused", why.name());
        }
    }
}

/// A relative error in parts per billion (saturating), for lines without floats.
pub fn ppb(rel: f32) -> u32 {
    let v = rel * 1e9;
    if v >= 0.0 {
        if v < u32::MAX as f32 {
            v as u32
        } else {
            u32::MAX
        }
    } else {
        0
    }
}

/// The fields of a table error (`table=<reason> ...`; errors in parts per billion).
pub fn table_error(line: &mut Line, e: &TableError) {
    match e {
        TableError::BadConfig => line.ks("table", "bad-config"),
        TableError::NonFinite { scaler, .. } => line.ks("table", "non-finite").ks("scaler", scaler),
        TableError::TooManyKinks { scaler, segments } => line
            .ks("table", "too-many-kinks")
            .ks("scaler", scaler)
            .kv("segments", *segments as u32),
        TableError::ExceedsBound {
            scaler,
            max_rel_error,
            bound,
            segments,
            ..
        } => line
            .ks("table", "exceeds-bound")
            .ks("scaler", scaler)
            .kv("segments", *segments as u32)
            .kv("max_rel_error_ppb", ppb(*max_rel_error))
            .kv("bound_ppb", ppb(*bound)),
    };
}

/// `digest chunk=<c> first=<k> steps=<n> crc=0x<crc>`.
pub fn digest(line: &mut Line, chunk: u32, first: u32, steps: u32, crc: u32) {
    line.str("digest")
        .kv("chunk", chunk)
        .kv("first", first)
        .kv("steps", steps)
        .kx("crc", crc);
}

/// One step record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepRecord {
    /// Sample index since start.
    pub k: u32,
    /// Velocity handed to the estimator \[m/s\] (NaN when the sensor path had none).
    pub velocity_m_s: f32,
    /// Force estimate \[N\].
    pub force_n: f32,
    /// [`nemm_core::Flags`] bits of the step.
    pub estimator_flags: u8,
    /// `FW_*` bits.
    pub firmware_flags: u8,
    /// SysTick ticks from the period start to the end of the step (0 on overrun).
    pub ticks: u16,
    /// The observer's part (bench-controller mode).
    pub observer: Option<ObserverRecord>,
}

/// The observer's part of a step record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObserverRecord {
    /// The load cell's force handed to the observer \[N\] (NaN on a load-cell fault).
    pub measured_force_n: f32,
    /// The estimate of alpha.
    pub alpha: f32,
    /// Its band (half-width).
    pub band: f32,
    /// [`nemm_core::ObserverFlags`] bits.
    pub flags: u8,
}

impl StepRecord {
    /// Writes the `s` line.
    pub fn write(&self, line: &mut Line) {
        line.str("s ")
            .dec(self.k)
            .str(" ")
            .hex_bare(self.velocity_m_s.to_bits(), 8)
            .str(" ")
            .hex_bare(self.force_n.to_bits(), 8)
            .str(" ")
            .hex_bare(u32::from(self.estimator_flags), 2)
            .str(" ")
            .hex_bare(u32::from(self.firmware_flags), 2)
            .str(" ")
            .dec(u32::from(self.ticks));
        if let Some(o) = &self.observer {
            line.kx("measured", o.measured_force_n.to_bits())
                .kx("alpha", o.alpha.to_bits())
                .kx("band", o.band.to_bits())
                .key("flags")
                .str("0x")
                .hex_bare(u32::from(o.flags), 2);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_numbers_and_records() {
        let mut l = Line::new();
        l.str("x")
            .kv("a", 0)
            .kv("b", 4_294_967_295)
            .kx("c", 0xdead_beef);
        assert_eq!(l.finish(), b"x a=0 b=4294967295 c=0xdeadbeef\n");
        let mut l = Line::new();
        StepRecord {
            k: 12,
            velocity_m_s: 1.0,
            force_n: -2.0,
            estimator_flags: 0x05,
            firmware_flags: FW_PRIMING,
            ticks: 321,
            observer: None,
        }
        .write(&mut l);
        assert_eq!(l.as_bytes(), b"s 12 3f800000 c0000000 05 04 321");
        let mut l = Line::new();
        StepRecord {
            k: 10492,
            velocity_m_s: 1.0,
            force_n: -2.0,
            estimator_flags: 0,
            firmware_flags: 0,
            ticks: 0,
            observer: Some(ObserverRecord {
                measured_force_n: 2.0,
                alpha: 0.25,
                band: 0.5,
                flags: 0x21,
            }),
        }
        .write(&mut l);
        assert_eq!(
            l.as_bytes(),
            &b"s 10492 3f800000 c0000000 00 00 0 measured=0x40000000 alpha=0x3e800000 \
               band=0x3f000000 flags=0x21"[..]
        );
    }

    #[test]
    fn typed_errors_have_stable_names() {
        let mut l = Line::new();
        decode_error(
            &mut l,
            &DecodeError::UnsupportedVersion {
                found: 2,
                supported: 1,
            },
        );
        assert_eq!(
            l.as_bytes(),
            b"weights-error source=decode kind=unsupported-version found=2 supported=1"
        );
        let mut l = Line::new();
        decode_error(
            &mut l,
            &DecodeError::Invalid(ModelError::NonFinite { field: "dt_s" }),
        );
        assert_eq!(
            l.as_bytes(),
            b"weights-error source=decode kind=invalid reason=non-finite field=dt_s"
        );
        let mut l = Line::new();
        digest(&mut l, 2, 2000, 1000, 0xc0ffee);
        assert_eq!(
            l.as_bytes(),
            b"digest chunk=2 first=2000 steps=1000 crc=0x00c0ffee"
        );
        let mut l = Line::new();
        slot_error(&mut l, &SlotError::Empty);
        assert_eq!(l.as_bytes(), b"weights-error source=slot kind=empty");
        let mut l = Line::new();
        observer_error(
            &mut l,
            &ObserverError::Estimator(EstimatorError::AlphaPerSampleInTableMode),
        );
        assert_eq!(
            l.as_bytes(),
            b"observer-error kind=estimator reason=alpha-per-sample-in-table-mode"
        );
        let mut l = Line::new();
        observer_error(&mut l, &ObserverError::Setting("horizon_s"));
        assert_eq!(
            l.as_bytes(),
            b"observer-error kind=setting setting=horizon_s"
        );
    }

    #[test]
    fn truncates_instead_of_overflowing() {
        let mut l = Line::new();
        for _ in 0..100 {
            l.str("abc");
        }
        assert_eq!(l.finish().len(), LINE_CAPACITY);
        assert_eq!(l.as_bytes().last(), Some(&b'\n'));
    }
}
