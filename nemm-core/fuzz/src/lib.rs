//! Shared code of the decoder fuzz targets and the seed writer.

use nemm_core::CRC;
use nemm_core::{
    decode, encode_to_vec, read_header, DecodeError, Estimator, EstimatorConfig, Header, Model,
    ModelKind, Sample, DEFAULT_PARAM_CAPACITY, FORMAT_VERSION,
};

/// Capacities the targets decode into: tiny (most scalers over capacity), exactly the
/// default example's scaler size, and the default.
fn check_with_capacity<const P: usize>(data: &[u8]) {
    match decode::<P>(data) {
        Ok(model) => check_model(&model),
        Err(DecodeError::OverCapacity { needed, capacity }) => {
            assert!(needed > capacity && capacity == P);
        }
        Err(_) => {}
    }
}

/// Every property a decoded model must have.
pub fn check_model<const P: usize>(model: &Model<P>) {
    assert_eq!(model.validate(), Ok(()));
    let blob = encode_to_vec(model).expect("a decoded model re-encodes");
    let again: Model<P> = decode(&blob).expect("a re-encoded model decodes");
    assert_eq!(&again, model);
    if let Ok(mut est) = Estimator::new(model, EstimatorConfig::new(0.15)) {
        for k in 0..64 {
            let v = match k % 16 {
                7 => f32::NAN,
                11 => 1e30,
                _ => (k as f32 * 0.3).sin(),
            };
            // Every other step with a position (finite, huge or NaN), the others without.
            let sample = match k % 4 {
                0 => Sample::new(v),
                1 => Sample::new(v).with_position((k as f32 * 0.1).cos()),
                2 => Sample::new(v).with_position(if k % 8 == 2 { f32::NAN } else { -1e30 }),
                _ => Sample::new(v).with_position(0.0),
            };
            let e = est
                .step(sample)
                .expect("a sample without alpha is never refused");
            assert!(e.force_n.is_finite());
        }
    }
}

/// Decodes `data` into three capacities and reads its header; panics only on a violated
/// property.
pub fn check_blob(data: &[u8]) {
    let _ = read_header(data);
    check_with_capacity::<64>(data);
    check_with_capacity::<1313>(data);
    check_with_capacity::<DEFAULT_PARAM_CAPACITY>(data);
}

const KINDS: [ModelKind; 4] = [
    ModelKind::Sem,
    ModelKind::LinearEmm,
    ModelKind::NemmLight,
    ModelKind::Nemm,
];

/// `[kind, max_scaler_params u16 LE] ++ body` -> header + body + CRC.
pub fn wrap_body(data: &[u8]) -> Option<Vec<u8>> {
    let (&[kind, lo, hi], body) = data.split_first_chunk::<3>()?;
    let header = Header {
        magic: nemm_core::MAGIC,
        version: FORMAT_VERSION,
        kind: KINDS[usize::from(kind) % 4],
        max_scaler_params: u32::from(u16::from_le_bytes([lo, hi])),
        body_len: u32::try_from(body.len()).ok()?,
    };
    let mut hbuf = [0u8; nemm_core::MAX_HEADER_LEN];
    let mut out = postcard::to_slice(&header, &mut hbuf).ok()?.to_vec();
    out.extend_from_slice(body);
    let crc = CRC.checksum(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    Some(out)
}

/// The inverse of [`wrap_body`] for a valid blob: the `decode_body` seed of a model.
pub fn unwrap_body(blob: &[u8]) -> Option<Vec<u8>> {
    let h = read_header(blob).ok()?;
    let body_len = h.body_len as usize;
    let header_len = blob.len().checked_sub(body_len + nemm_core::CRC_LEN)?;
    let kind = KINDS.iter().position(|&k| k == h.kind)? as u8;
    let max = u16::try_from(h.max_scaler_params).ok()?.to_le_bytes();
    let mut out = vec![kind, max[0], max[1]];
    out.extend_from_slice(blob.get(header_len..header_len + body_len)?);
    Some(out)
}
