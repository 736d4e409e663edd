//! The weights of one MLP ([`MlpParams`]): the flat layout, in-place decoding and the
//! views of its layers.

use super::*;

/// Weights of one MLP, in the layout of the module docs.
///
/// `clone_from` copies in place, and `Deserialize::deserialize_in_place` decodes the
/// parameters where they are (no temporary of `P` floats on the stack either way).
#[derive(Debug, PartialEq, Serialize)]
pub struct MlpParams<const P: usize> {
    /// Number of inputs `d` (1 or 2).
    pub inputs: u8,
    /// Hidden width `H` (1..=32).
    pub hidden: u8,
    /// Number of hidden layers `L` (1..=9).
    pub layers: u8,
    /// All parameters, flat.
    pub params: heapless::Vec<f32, P>,
}

impl<const P: usize> Clone for MlpParams<P> {
    fn clone(&self) -> Self {
        let mut c = Self {
            inputs: 0,
            hidden: 0,
            layers: 0,
            params: heapless::Vec::new(),
        };
        c.clone_from(self);
        c
    }

    fn clone_from(&mut self, source: &Self) {
        self.inputs = source.inputs;
        self.hidden = source.hidden;
        self.layers = source.layers;
        self.params.clear();
        // Same capacity `P`: cannot fail.
        let _ = self.params.extend_from_slice(&source.params);
    }
}

/// `Deserialize` by hand (the wire format is the derived one: the four fields in order, the
/// parameters as a length-prefixed sequence) so that the parameters are decoded straight
/// into the existing vector.
mod de {
    use super::MlpParams;
    use core::fmt;
    use serde::de::{self, DeserializeSeed, Deserializer, SeqAccess, Visitor};
    use serde::Deserialize;

    const FIELDS: &[&str] = &["inputs", "hidden", "layers", "params"];

    /// Appends a sequence of `f32` to a cleared vector.
    struct Params<'a, const P: usize>(&'a mut heapless::Vec<f32, P>);

    impl<'de, const P: usize> Visitor<'de> for Params<'_, P> {
        type Value = ();
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            write!(f, "at most {P} parameters")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
            self.0.clear();
            while let Some(v) = seq.next_element::<f32>()? {
                if self.0.push(v).is_err() {
                    return Err(de::Error::invalid_length(P + 1, &self));
                }
            }
            Ok(())
        }
    }

    impl<'de, const P: usize> DeserializeSeed<'de> for Params<'_, P> {
        type Value = ();
        fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            d.deserialize_seq(self)
        }
    }

    struct Fields<'a, const P: usize>(&'a mut MlpParams<P>);

    impl<'de, const P: usize> Visitor<'de> for Fields<'_, P> {
        type Value = ();
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("the fields of an MLP")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
            let m = self.0;
            for (i, field) in [&mut m.inputs, &mut m.hidden, &mut m.layers]
                .into_iter()
                .enumerate()
            {
                *field = seq
                    .next_element()?
                    .ok_or_else(|| de::Error::invalid_length(i, &"the fields of an MLP"))?;
            }
            seq.next_element_seed(Params(&mut m.params))?
                .ok_or_else(|| de::Error::invalid_length(3, &"the fields of an MLP"))
        }
    }

    impl<'de, const P: usize> Deserialize<'de> for MlpParams<P> {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            let mut m = MlpParams {
                inputs: 0,
                hidden: 0,
                layers: 0,
                params: heapless::Vec::new(),
            };
            Self::deserialize_in_place(d, &mut m)?;
            Ok(m)
        }

        fn deserialize_in_place<D: Deserializer<'de>>(
            d: D,
            place: &mut Self,
        ) -> Result<(), D::Error> {
            d.deserialize_struct("MlpParams", FIELDS, Fields(place))
        }
    }
}

/// One hidden layer's parameters, borrowed from the flat vector.
#[derive(Debug, Clone, Copy)]
pub struct LayerView<'a> {
    /// Weight matrix, row-major `H x in`.
    pub w: &'a [f32],
    /// Bias, `H`.
    pub b: &'a [f32],
    /// LayerNorm gain, `H`.
    pub gamma: &'a [f32],
    /// LayerNorm offset, `H`.
    pub beta: &'a [f32],
}

/// Splits `n` items off the front of `s`, or `None`.
pub(super) fn take<'a>(s: &mut &'a [f32], n: usize) -> Option<&'a [f32]> {
    let (head, tail) = s.split_at_checked(n)?;
    *s = tail;
    Some(head)
}

impl<const P: usize> MlpParams<P> {
    /// Builds from dimensions and a parameter slice, checking the shape.
    pub fn new(inputs: u8, hidden: u8, layers: u8, params: &[f32]) -> Result<Self, ShapeError> {
        let mut v = heapless::Vec::new();
        let expected = param_count(inputs as usize, hidden as usize, layers as usize);
        if expected > P {
            return Err(ShapeError::OverCapacity {
                needed: expected,
                capacity: P,
            });
        }
        v.extend_from_slice(params)
            .map_err(|_| ShapeError::ParamCountMismatch {
                expected,
                found: params.len(),
            })?;
        let m = Self {
            inputs,
            hidden,
            layers,
            params: v,
        };
        m.check_shape()?;
        Ok(m)
    }

    /// An MLP with `inputs` inputs and no weights (width 0, no layers, no parameters): the
    /// MLP of a coefficient whose scale is a cumulative scaler ([`crate::cumulative`]), which
    /// keeps the scaler's bounds beside it. [`Self::check_shape`] refuses it: whether it
    /// is acceptable is the model's decision (it is only beside a cumulative scaler).
    pub const fn without_weights(inputs: u8) -> Self {
        Self {
            inputs,
            hidden: 0,
            layers: 0,
            params: heapless::Vec::new(),
        }
    }

    /// True for an MLP without weights ([`Self::without_weights`], any input count).
    pub fn is_without_weights(&self) -> bool {
        self.hidden == 0 && self.layers == 0 && self.params.is_empty()
    }

    /// Checks dimensions against the limits, the capacity and the parameter count.
    pub fn check_shape(&self) -> Result<(), ShapeError> {
        let (d, h, l) = (
            self.inputs as usize,
            self.hidden as usize,
            self.layers as usize,
        );
        if !(1..=MAX_INPUTS).contains(&d)
            || !(1..=MAX_HIDDEN).contains(&h)
            || !(1..=MAX_LAYERS).contains(&l)
        {
            return Err(ShapeError::DimensionOutOfRange);
        }
        let expected = param_count(d, h, l);
        if expected > P {
            return Err(ShapeError::OverCapacity {
                needed: expected,
                capacity: P,
            });
        }
        if self.params.len() != expected {
            return Err(ShapeError::ParamCountMismatch {
                expected,
                found: self.params.len(),
            });
        }
        Ok(())
    }

    /// The layout of the parameters ([`ScalerLayout`], no branch).
    pub fn layout(&self) -> ScalerLayout {
        ScalerLayout::mlp(
            self.inputs as usize,
            self.hidden as usize,
            self.layers as usize,
        )
    }

    /// Sets the first layer's weights of the last input (the alpha column of a scaler) to
    /// zero, so that the MLP does not see `alpha` (an alpha branch then carries the whole
    /// alpha dependence). Weights outside the parameter vector are left alone.
    pub fn clear_alpha_column(&mut self) {
        let layout = self.layout();
        let last = layout.inputs.saturating_sub(1);
        for i in 0..layout.hidden {
            if let Some(w) = layout
                .first_layer_weight(i, last)
                .and_then(|k| self.params.get_mut(k))
            {
                *w = 0.0;
            }
        }
    }

    /// Hidden layer `l` (0-based), or `None` if out of range or the shape is inconsistent.
    pub fn layer(&self, l: usize) -> Option<LayerView<'_>> {
        let r = self.layout().layer(l)?;
        let p: &[f32] = &self.params;
        Some(LayerView {
            w: p.get(r.w)?,
            b: p.get(r.b)?,
            gamma: p.get(r.gamma)?,
            beta: p.get(r.beta)?,
        })
    }

    /// Output weights `w_o` (`H`) and bias `b_o`.
    pub fn output(&self) -> Option<(&[f32], f32)> {
        let (w, b) = self.layout().output()?;
        Some((self.params.get(w)?, *self.params.get(b)?))
    }

    /// Reference forward pass: raw output `z` for normalised inputs `x` (length `inputs`),
    /// [`ScalerView::raw`] in `f32` with fused multiply-adds.
    ///
    /// Returns `None` only if the shape is inconsistent (never for a validated model).
    pub fn forward(&self, x: &[f32]) -> Option<f32> {
        if x.len() != self.inputs as usize {
            return None;
        }
        let view = self.view(None)?;
        let fold = view.fold::<math::Fused, f32>(x.get(1).copied().unwrap_or(0.0), 0.0)?;
        view.raw::<math::Fused, f32>(&fold, *x.first()?, None)
    }

    /// The lane-generic view of these weights ([`ScalerView`]) with the alpha branch
    /// `branch`, if any; `None` if the branch's parameter count does not match its shape.
    pub fn view<'a>(&'a self, branch: Option<&'a AlphaBranch>) -> Option<ScalerView<'a, f32>> {
        let layout = self.layout().with_branch(branch.map(AlphaBranch::layout));
        let (bw, direction): (&[f32], _) = match branch {
            Some(b) => (&b.params, b.direction),
            None => (&[], Direction::None),
        };
        (bw.len() == layout.branch_len()).then_some(ScalerView {
            layout,
            mlp: &self.params,
            branch: bw,
            direction,
        })
    }
}
