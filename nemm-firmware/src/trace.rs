//! The recorded bench trace the replay device serves, as stored in flash.
//!
//! ```text
//! offset  field
//!  0      magic "NTRC"
//!  4      version: u16 LE = 2
//!  6      reserved: u16 LE = 0
//!  8      sample_rate_hz: f32 LE
//! 12      oil_loss (alpha): f32 LE, the run's oil-loss level
//! 16      n_samples: u32 LE
//! 20      n_samples x (displacement_m: f32 LE, velocity_m_s: f32 LE, force_n: f32 LE)
//! ```
//!
//! `displacement_m` is the stroke as recorded (positive = extension); NaN marks a dropout
//! in the recording (served as an invalid conversion). `velocity_m_s` is the bench's own
//! velocity channel if the recording has one (NaN otherwise); `force_n` is the measured force
//! (NaN if the recording has none, e.g. the synthetic run). The firmware reads neither: the
//! host tests compare the estimates against them (the end-to-end force error). `build.rs`
//! writes this format from the project's run CSV (`time_s,displacement_m,force_n[,
//! velocity_m_s]`) or generates a synthetic run.

/// Magic bytes of a trace.
pub const MAGIC: [u8; 4] = *b"NTRC";
/// Format version.
pub const VERSION: u16 = 2;
/// Header length in bytes.
pub const HEADER_LEN: usize = 20;
/// Bytes per sample.
pub const SAMPLE_LEN: usize = 12;

/// Bytes of a trace of `n` samples (`None` on overflow).
pub const fn encoded_len(n: usize) -> Option<usize> {
    match n.checked_mul(SAMPLE_LEN) {
        Some(b) => b.checked_add(HEADER_LEN),
        None => None,
    }
}

/// Writes a trace of `samples` (`(displacement_m, velocity_m_s, force_n)` each) recorded at
/// `sample_rate_hz` from a damper at oil loss `oil_loss` into the start of `out`; returns
/// the bytes written, `None` if `out` is too short or there are more than `u32::MAX` samples.
/// The one writer of the format: `build.rs` and the host tests use it.
pub fn encode(
    sample_rate_hz: f32,
    oil_loss: f32,
    samples: &[(f32, f32, f32)],
    out: &mut [u8],
) -> Option<usize> {
    let len = encoded_len(samples.len())?;
    let out = out.get_mut(..len)?;
    let n = u32::try_from(samples.len()).ok()?;
    let (header, body) = out.split_at_mut(HEADER_LEN);
    let mut words = [0u32; 5];
    for (w, v) in words.iter_mut().zip([
        u32::from_le_bytes(MAGIC),
        u32::from(VERSION),
        sample_rate_hz.to_bits(),
        oil_loss.to_bits(),
        n,
    ]) {
        *w = v;
    }
    for (chunk, w) in header.chunks_exact_mut(4).zip(words) {
        chunk.copy_from_slice(&w.to_le_bytes());
    }
    for (chunk, (x, v, f)) in body.chunks_exact_mut(SAMPLE_LEN).zip(samples) {
        for (field, value) in chunk.chunks_exact_mut(4).zip([x, v, f]) {
            field.copy_from_slice(&value.to_le_bytes());
        }
    }
    Some(len)
}

/// Why a trace is not usable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TraceError {
    /// Shorter than its header or its sample count says.
    Truncated,
    /// Not a trace (magic).
    BadMagic,
    /// Another format version.
    UnsupportedVersion(u16),
    /// Sample rate not finite and positive, or oil loss outside `[0, 1]`.
    BadHeader,
}

/// A parsed view of a trace in flash.
#[derive(Debug, Clone, Copy)]
pub struct Trace<'a> {
    /// Sample rate \[Hz\].
    pub sample_rate_hz: f32,
    /// Oil-loss level `alpha` of the recorded damper.
    pub oil_loss: f32,
    samples: &'a [u8],
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    let s = b.get(at..at.checked_add(4)?)?;
    let mut w = [0u8; 4];
    w.copy_from_slice(s);
    Some(u32::from_le_bytes(w))
}

impl<'a> Trace<'a> {
    /// Parses and checks the header.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, TraceError> {
        let magic = bytes.get(..4).ok_or(TraceError::Truncated)?;
        if magic != MAGIC {
            return Err(TraceError::BadMagic);
        }
        let word = |at| u32_at(bytes, at).ok_or(TraceError::Truncated);
        let version = (word(4)? & 0xFFFF) as u16;
        if version != VERSION {
            return Err(TraceError::UnsupportedVersion(version));
        }
        let sample_rate_hz = f32::from_bits(word(8)?);
        let oil_loss = f32::from_bits(word(12)?);
        let n = word(16)? as usize;
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0 && (0.0..=1.0).contains(&oil_loss))
        {
            return Err(TraceError::BadHeader);
        }
        let len = n.checked_mul(SAMPLE_LEN).ok_or(TraceError::Truncated)?;
        let samples = bytes
            .get(HEADER_LEN..)
            .and_then(|s| s.get(..len))
            .ok_or(TraceError::Truncated)?;
        Ok(Self {
            sample_rate_hz,
            oil_loss,
            samples,
        })
    }

    /// The first `n` samples (all of them if there are fewer).
    pub fn prefix(self, n: usize) -> Self {
        let len = n.saturating_mul(SAMPLE_LEN).min(self.samples.len());
        Self {
            samples: self.samples.get(..len).unwrap_or(self.samples),
            ..self
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.samples.len() / SAMPLE_LEN
    }

    /// True without samples.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Recorded displacement \[m\] of sample `i` (NaN for a dropout), `None` past the end.
    pub fn displacement_m(&self, i: usize) -> Option<f32> {
        u32_at(self.samples, i.checked_mul(SAMPLE_LEN)?).map(f32::from_bits)
    }

    /// The bench's velocity of sample `i` \[m/s\] (NaN if not recorded), `None` past the end.
    pub fn velocity_m_s(&self, i: usize) -> Option<f32> {
        u32_at(self.samples, i.checked_mul(SAMPLE_LEN)?.checked_add(4)?).map(f32::from_bits)
    }

    /// The measured force of sample `i` \[N\] (NaN if not recorded), `None` past the end.
    pub fn force_n(&self, i: usize) -> Option<f32> {
        u32_at(self.samples, i.checked_mul(SAMPLE_LEN)?.checked_add(8)?).map(f32::from_bits)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    fn trace_bytes(samples: &[(f32, f32, f32)]) -> Vec<u8> {
        let mut b = std::vec![0; encoded_len(samples.len()).unwrap()];
        assert_eq!(encode(10_000.0, 0.15, samples, &mut b), Some(b.len()));
        assert_eq!(encode(10_000.0, 0.15, samples, &mut b[1..]), None);
        b
    }

    #[test]
    fn parses_samples_and_rejects_damage() {
        let b = trace_bytes(&[(0.001, 0.5, 12.5), (f32::NAN, -0.25, f32::NAN)]);
        let t = Trace::parse(&b).unwrap();
        assert_eq!((t.len(), t.sample_rate_hz, t.oil_loss), (2, 10_000.0, 0.15));
        assert_eq!(t.displacement_m(0), Some(0.001));
        assert!(t.displacement_m(1).unwrap().is_nan());
        assert_eq!(t.velocity_m_s(1), Some(-0.25));
        assert_eq!(t.force_n(0), Some(12.5));
        assert!(t.force_n(1).unwrap().is_nan());
        assert_eq!(t.force_n(2), None);
        assert_eq!(t.displacement_m(2), None);
        assert_eq!(
            Trace::parse(&b[..b.len() - 1]).unwrap_err(),
            TraceError::Truncated
        );
        let mut bad = b.clone();
        bad[0] = b'X';
        assert_eq!(Trace::parse(&bad).unwrap_err(), TraceError::BadMagic);
        let mut bad = b.clone();
        bad[4] = 9;
        assert_eq!(
            Trace::parse(&bad).unwrap_err(),
            TraceError::UnsupportedVersion(9)
        );
        assert_eq!(t.prefix(1).len(), 1);
        assert_eq!(t.prefix(1).displacement_m(1), None);
        assert_eq!(t.prefix(5).len(), 2);
        let mut bad = b;
        bad[12..16].copy_from_slice(&2.0f32.to_le_bytes());
        assert_eq!(Trace::parse(&bad).unwrap_err(), TraceError::BadHeader);
    }
}
