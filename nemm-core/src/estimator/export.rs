//! A blob with the fast-path tables of estimators: the tables section
//! ([`crate::format::tables`]) written from table-mode estimators, so that a firmware in
//! [`EvalMode::Table`](crate::EvalMode::Table) boots without building them.

use super::Estimator;
use crate::format::tables::TableLevel;
use crate::format::{self, EncodeError};
use crate::limits::MAX_TABLE_LEVELS;
use crate::model::Model;

/// The tables of each estimator of `levels`; [`EncodeError::Tables`] if one is not in table
/// mode or has no neural coefficient, or there are more than [`MAX_TABLE_LEVELS`].
fn table_levels<'a, const P: usize, const T: usize>(
    levels: &[&'a Estimator<P, T>],
) -> Result<heapless::Vec<TableLevel<'a, T>, MAX_TABLE_LEVELS>, EncodeError> {
    let mut out = heapless::Vec::new();
    for est in levels {
        let level = est.table_level().ok_or(EncodeError::Tables)?;
        out.push(level).map_err(|_| EncodeError::Tables)?;
    }
    Ok(out)
}

/// Length in bytes of the blob of `model` with the tables of `levels` (see
/// [`encode_with_tables`]).
pub fn encoded_len_with_tables<const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[&Estimator<P, T>],
) -> Result<usize, EncodeError> {
    format::encoded_len_with_levels(model, &table_levels(levels)?)
}

/// Encodes a validated model with precomputed fast-path tables: the tables of each
/// estimator of `levels` (at most [`MAX_TABLE_LEVELS`], each loaded from `model` in
/// [`crate::EvalMode::Table`]) at its alpha, bit for bit (see [`crate::StoredTables`]).
/// `buf` needs at least [`encoded_len_with_tables`] bytes; returns the blob (a prefix of
/// `buf`). An estimator that is not in table mode, or whose tables do not fit the model
/// (another kind, another domain), is refused with [`EncodeError::Tables`].
pub fn encode_with_tables<'b, const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[&Estimator<P, T>],
    buf: &'b mut [u8],
) -> Result<&'b [u8], EncodeError> {
    format::encode_with_levels(model, &table_levels(levels)?, buf)
}

/// [`encode_with_tables`] into a new vector.
#[cfg(feature = "std")]
pub fn encode_to_vec_with_tables<const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[&Estimator<P, T>],
) -> Result<std::vec::Vec<u8>, EncodeError> {
    format::encode_to_vec_with_levels(model, &table_levels(levels)?)
}
