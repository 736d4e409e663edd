//! In-place deserialization of [`Body`] (see its docs).

use super::Body;
use core::fmt;
use nemm_kernels::emm::EmmConstants;
use nemm_kernels::mlp::Scaler;
use nemm_kernels::sem::SemMap;
use serde::de::{
    self, DeserializeSeed, Deserializer, EnumAccess, SeqAccess, VariantAccess, Visitor,
};
use serde::Deserialize;

const VARIANTS: &[&str] = &["Sem", "LinearEmm", "NemmLight", "Nemm"];
const LIGHT_FIELDS: &[&str] = &["emm", "b_fl"];
const NEMM_FIELDS: &[&str] = &["emm", "b_fl", "b_pr", "k_pr"];
const ZERO: EmmConstants = EmmConstants {
    b_fl_ns_per_m: 0.0,
    b_pr_ns_per_m: 0.0,
    k_pr_n_per_m: 0.0,
    t_pr_s: 0.0,
};

/// The empty scaler of a variant switch. An unoptimised build copies the constant into
/// place (a call's result would be one more copy on the stack); an optimised build writes
/// the few fields of an inlined constructor in place (the constant would be copied through
/// the stack).
#[cfg(debug_assertions)]
macro_rules! empty_scaler {
    () => {
        Scaler::EMPTY
    };
}

#[cfg(not(debug_assertions))]
macro_rules! empty_scaler {
    () => {
        Scaler {
            mlp: nemm_kernels::mlp::MlpParams {
                inputs: 0,
                hidden: 0,
                layers: 0,
                params: heapless::Vec::new(),
            },
            s_min: 0.0,
            s_max: 0.0,
        }
    };
}

// The variant switches, each out of line: an unoptimised build gives every temporary its
// own stack slot, so inside the visitor the three would add up; here only the one in use
// is on the stack. An optimised build writes the tag and the vector lengths in place.

#[inline(never)]
fn switch_to_sem<const P: usize>(place: &mut Body<P>) {
    *place = Body::Sem(SemMap::empty());
}

#[inline(never)]
fn switch_to_linear_emm<const P: usize>(place: &mut Body<P>) {
    *place = Body::LinearEmm(ZERO);
}

#[inline(never)]
fn switch_to_nemm_light<const P: usize>(place: &mut Body<P>) {
    *place = Body::NemmLight {
        emm: ZERO,
        b_fl: empty_scaler!(),
    };
}

#[inline(never)]
fn switch_to_nemm<const P: usize>(place: &mut Body<P>) {
    *place = Body::Nemm {
        emm: ZERO,
        b_fl: empty_scaler!(),
        b_pr: empty_scaler!(),
        k_pr: empty_scaler!(),
    };
}

/// Deserializes a value into an existing place.
struct InPlace<'a, T>(&'a mut T);

impl<'de, T: Deserialize<'de>> DeserializeSeed<'de> for InPlace<'_, T> {
    type Value = ();
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        T::deserialize_in_place(d, self.0)
    }
}

/// Fills the fields of a struct variant in order.
struct Fields<'a, const P: usize> {
    emm: &'a mut EmmConstants,
    scalers: [Option<&'a mut Scaler<P>>; 3],
}

impl<'de, const P: usize> Visitor<'de> for Fields<'_, P> {
    type Value = ();
    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("the fields of a NEMM body")
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        let n = 1 + self.scalers.iter().filter(|s| s.is_some()).count();
        if seq.next_element_seed(InPlace(self.emm))?.is_none() {
            return Err(de::Error::invalid_length(0, &self));
        }
        let mut i = 1;
        for s in self.scalers.into_iter().flatten() {
            if seq.next_element_seed(InPlace(s))?.is_none() {
                return Err(de::Error::invalid_length(i, &"the fields of a NEMM body"));
            }
            i += 1;
        }
        debug_assert_eq!(i, n);
        Ok(())
    }
}

struct BodyVisitor<'a, const P: usize>(&'a mut Body<P>);

impl<'de, const P: usize> Visitor<'de> for BodyVisitor<'_, P> {
    type Value = ();
    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("a NEMM model body")
    }
    fn visit_enum<A: EnumAccess<'de>>(self, data: A) -> Result<(), A::Error> {
        let (idx, variant) = data.variant::<u32>()?;
        let place = self.0;
        // Switch the place to the variant first (cheap: empty vectors), then fill its
        // fields where they are.
        match idx {
            0 => {
                if !matches!(place, Body::Sem(_)) {
                    switch_to_sem(place);
                }
                match place {
                    Body::Sem(m) => variant.newtype_variant_seed(InPlace(m)),
                    _ => Err(de::Error::custom("variant switch")),
                }
            }
            1 => {
                if !matches!(place, Body::LinearEmm(_)) {
                    switch_to_linear_emm(place);
                }
                match place {
                    Body::LinearEmm(e) => variant.newtype_variant_seed(InPlace(e)),
                    _ => Err(de::Error::custom("variant switch")),
                }
            }
            2 => {
                if !matches!(place, Body::NemmLight { .. }) {
                    switch_to_nemm_light(place);
                }
                match place {
                    Body::NemmLight { emm, b_fl } => variant.struct_variant(
                        LIGHT_FIELDS,
                        Fields {
                            emm,
                            scalers: [Some(b_fl), None, None],
                        },
                    ),
                    _ => Err(de::Error::custom("variant switch")),
                }
            }
            3 => {
                if !matches!(place, Body::Nemm { .. }) {
                    switch_to_nemm(place);
                }
                match place {
                    Body::Nemm {
                        emm,
                        b_fl,
                        b_pr,
                        k_pr,
                    } => variant.struct_variant(
                        NEMM_FIELDS,
                        Fields {
                            emm,
                            scalers: [Some(b_fl), Some(b_pr), Some(k_pr)],
                        },
                    ),
                    _ => Err(de::Error::custom("variant switch")),
                }
            }
            other => Err(de::Error::invalid_value(
                de::Unexpected::Unsigned(u64::from(other)),
                &"variant index 0 <= i < 4",
            )),
        }
    }
}

impl<'de, const P: usize> Deserialize<'de> for Body<P> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let mut b = Body::LinearEmm(ZERO);
        Self::deserialize_in_place(d, &mut b)?;
        Ok(b)
    }

    fn deserialize_in_place<D: Deserializer<'de>>(d: D, place: &mut Self) -> Result<(), D::Error> {
        d.deserialize_enum("Body", VARIANTS, BodyVisitor(place))
    }
}
