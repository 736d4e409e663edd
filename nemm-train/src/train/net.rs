//! The trainable parameters as burn modules, and their exchange with the flat nemm-core
//! layout used by the rollout adjoint.
//!
//! - [`ScalerNet`]: `L` blocks of `Linear -> LayerNorm -> LeakyReLU` and a `Linear` output:
//!   the architecture of nemm-core's scalers. burn stores a `Linear` weight as `[in, out]`;
//!   nemm-core as row-major `[out][in]`: conversions transpose.
//! - [`EmmNet`]: the EMM constants as `ln(b_fl,ini), ln(b_pr,ini), ln(k_pr,ini), ln(T_pr)`
//!   (trained in log space so that they stay positive) and the optional scalers.
//!
//! burn serves what it is good at: the parameters, Adam with gradient clipping, the L2 term,
//! the quasi-static `b_fl` regression (eq. 41) and the physics-inconsistency losses on grids
//! (eqs. 27-28, 34, 39-40), checkpoints. The rollout's gradient comes from
//! [`super::adjoint`] and is added with `EmmNet::add_rollout_grads` before one optimizer
//! step.

use super::adjoint::{
    BranchShape, CumulativeShape, RolloutGrads, RolloutParams, ScalerWeights, StaticParams,
};
use burn::module::{Module, Param};
use burn::nn::{LayerNorm, LayerNormConfig, LeakyRelu, Linear};
use burn::optim::GradientsParams;
use burn::tensor::activation::{leaky_relu, sigmoid, softmax};
use burn::tensor::{Device, Tensor, TensorData};
use nemm_core::Priors;
use nemm_kernels::lost_motion::LOST_MOTION_PARAMS;
use nemm_kernels::mlp::Direction;
use nemm_kernels::mlp::LEAKY_RELU_SLOPE;
use nemm_kernels::static_force::STATIC_PARAMS;

/// One hidden block.
#[derive(Module, Debug)]
pub(crate) struct Block {
    /// Linear map, weight `[in, out]`.
    pub(crate) linear: Linear,
    /// LayerNorm (eps 1e-5, biased variance: as nemm-core).
    pub(crate) norm: LayerNorm,
    /// LeakyReLU (slope 0.01: as nemm-core).
    pub(crate) act: LeakyRelu,
}

/// A scaler's alpha branch (`nemm_kernels::mlp::AlphaBranch`) as a burn module: per unit `k`,
/// `v_k leaky_relu(r_k x + u_k alpha_n + c_k)` with `v_k = theta_v,k^2`,
/// `u_k = d theta_u,k^2` (the direction `d` is in the [`ScalerSpec`]).
#[derive(Module, Debug)]
pub struct BranchNet {
    /// State weights `r` `[K]` (absent for `b_pr`).
    pub r: Option<Param<Tensor<1>>>,
    /// `theta_u` `[K]`.
    pub(crate) theta_u: Param<Tensor<1>>,
    /// Biases `c` `[K]`.
    pub c: Param<Tensor<1>>,
    /// `theta_v` `[K]`.
    pub(crate) theta_v: Param<Tensor<1>>,
}

/// An MLP scaler (and its alpha branch) as a burn module.
#[derive(Module, Debug)]
pub struct MlpNet {
    /// Hidden blocks.
    pub(crate) blocks: Vec<Block>,
    /// Output neuron, weight `[H, 1]`.
    pub out: Linear,
    /// The alpha branch, if any.
    pub branch: Option<BranchNet>,
}

/// Shape and output bounds of a scaler (not trained).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScalerSpec {
    /// Inputs (2: state and alpha; 1: alpha).
    pub inputs: usize,
    /// Hidden width.
    pub hidden: usize,
    /// Hidden layers.
    pub layers: usize,
    /// Lower bound of the scale factor.
    pub(crate) s_min: f32,
    /// Upper bound of the scale factor.
    pub(crate) s_max: f32,
    /// The alpha branch's shape, if the scaler has one.
    pub branch: Option<BranchShape>,
    /// The cumulative scaler's shape, if the scaler is one (`hidden`, `layers` are then 0).
    pub cumulative: Option<CumulativeShape>,
}

/// A cumulative scaler's parameters are stored divided by this factor: Adam moves every
/// parameter by about the learning rate per step, and one step of an MLP scaler moves its
/// raw output by up to `H` such steps at once, whereas each logit, log width, centre and gate
/// parameter of a cumulative scaler acts alone; stored this way they move ten times the
/// learning rate per step.
pub(crate) const CUMULATIVE_PARAM_SCALE: f32 = 10.0;

/// A cumulative scaler (`nemm_kernels::cumulative`) as a burn module: the groups of its
/// flat layout, each one tensor, stored divided by `CUMULATIVE_PARAM_SCALE`.
#[derive(Module, Debug)]
pub struct CumulativeNet {
    /// Logits `a` `[K + 1]` (constant part, then the units; the slack's logit is 0).
    pub(crate) a: Param<Tensor<1>>,
    /// Log widths `omega` `[K]`.
    pub(crate) omega: Param<Tensor<1>>,
    /// Centres `c` `[K]`.
    pub(crate) c: Param<Tensor<1>>,
    /// Gate slopes `gamma` `[K + 1]`.
    pub(crate) gamma: Param<Tensor<1>>,
    /// Gate biases `beta` `[K + 1]`.
    pub(crate) beta: Param<Tensor<1>>,
}

/// A neural scaler as a burn module: an MLP (the paper's) or a cumulative scaler.
#[derive(Module, Debug)]
pub enum ScalerNet {
    /// `Linear -> LayerNorm -> LeakyReLU` blocks, the output neuron and the alpha branch.
    Mlp(MlpNet),
    /// The cumulative scaler, whose force is monotone in the state by construction.
    Cumulative(CumulativeNet),
}

impl ScalerNet {
    /// Builds from flat weights (nemm-core's layout of the scaler's family).
    pub(crate) fn from_flat(s: &ScalerWeights<f32>, device: &Device) -> Self {
        match s.cumulative {
            Some(c) => ScalerNet::Cumulative(CumulativeNet::from_flat(&s.w, c.units, device)),
            None => ScalerNet::Mlp(MlpNet::from_flat(s, device)),
        }
    }

    /// Flat weights in nemm-core's layout.
    pub(crate) fn to_flat(&self) -> Vec<f32> {
        match self {
            ScalerNet::Mlp(n) => n.to_flat(),
            ScalerNet::Cumulative(n) => n.to_flat(),
        }
    }

    /// Scale factor for normalised inputs `[batch, inputs]` (alpha last): `[batch, 1]`.
    pub(crate) fn forward_scale(&self, x: Tensor<2>, spec: &ScalerSpec) -> Tensor<2> {
        match self {
            ScalerNet::Mlp(n) => n.forward_scale(x, spec),
            ScalerNet::Cumulative(n) => n.forward_scale(x, spec),
        }
    }

    /// The L2 term's sum of squared weights (`None` for a cumulative scaler, which has no
    /// linear maps and is bounded by construction).
    pub(crate) fn weight_sq_sum(&self) -> Option<Tensor<1>> {
        match self {
            ScalerNet::Mlp(n) => Some(n.weight_sq_sum()),
            ScalerNet::Cumulative(_) => None,
        }
    }

    /// Adds a flat gradient (nemm-core layout) to the parameters' entries in `gp`.
    pub(crate) fn add_flat_grads(&self, g: &[f32], gp: &mut GradientsParams, device: &Device) {
        match self {
            ScalerNet::Mlp(n) => n.add_flat_grads(g, gp, device),
            ScalerNet::Cumulative(n) => n.add_flat_grads(g, gp, device),
        }
    }
}

/// Adds `v` to the gradient of `p` in `gp` (registers it if there is none).
fn add_grad1(gp: &mut GradientsParams, p: &Param<Tensor<1>>, v: &[f32], dev: &Device) {
    let t = tensor1(v, dev);
    let t = match gp.remove::<1>(p.id) {
        Some(old) => old + t,
        None => t,
    };
    gp.register(p.id, t);
}

impl CumulativeNet {
    /// Splits flat weights (`nemm_kernels::cumulative`'s layout) of `units` units.
    fn from_flat(w: &[f32], units: usize, device: &Device) -> Self {
        assert_eq!(
            w.len(),
            nemm_kernels::cumulative::cumulative_param_count(units),
            "cumulative scaler weight count"
        );
        let mut at = 0;
        let mut take = |n: usize| {
            let stored: Vec<f32> = w[at..at + n]
                .iter()
                .map(|v| v / CUMULATIVE_PARAM_SCALE)
                .collect();
            at += n;
            Param::from_tensor(tensor1(&stored, device))
        };
        Self {
            a: take(units + 1),
            omega: take(units),
            c: take(units),
            gamma: take(units + 1),
            beta: take(units + 1),
        }
    }

    fn groups(&self) -> [&Param<Tensor<1>>; 5] {
        [&self.a, &self.omega, &self.c, &self.gamma, &self.beta]
    }

    fn to_flat(&self) -> Vec<f32> {
        self.groups()
            .iter()
            .flat_map(|p| to_vec(p.val()))
            .map(|v| v * CUMULATIVE_PARAM_SCALE)
            .collect()
    }

    /// A group's values (unscaled).
    fn value(p: &Param<Tensor<1>>) -> Tensor<1> {
        p.val().mul_scalar(CUMULATIVE_PARAM_SCALE)
    }

    fn add_flat_grads(&self, g: &[f32], gp: &mut GradientsParams, device: &Device) {
        let dev = plain(device);
        let mut at = 0;
        for p in self.groups() {
            let n = p.val().dims()[0];
            let scaled: Vec<f32> = g[at..at + n]
                .iter()
                .map(|v| v * CUMULATIVE_PARAM_SCALE)
                .collect();
            add_grad1(gp, p, &scaled, &dev);
            at += n;
        }
    }

    /// The scale `s_min + (s_max - s_min) (pi_0 + sum_k pi_k h(w_k x, c_k))` of the kernels'
    /// module docs for inputs `[batch, 2]` (state, alpha): `[batch, 1]`.
    fn forward_scale(&self, x: Tensor<2>, spec: &ScalerSpec) -> Tensor<2> {
        let direction = spec.cumulative.map_or(Direction::None, |c| c.direction);
        let [n, d] = x.dims();
        let device = x.device();
        let k = self.omega.val().dims()[0];
        let state = x.clone().narrow(1, 0, 1);
        let alpha = x.narrow(1, d - 1, 1);
        let row = |t: Tensor<1>, len: usize| t.reshape([1, len]);
        // Softmax over the K + 1 logits and the slack's 0.
        let logits = Tensor::cat(
            vec![Self::value(&self.a), Tensor::<1>::zeros([1], &device)],
            0,
        );
        let p = softmax(logits, 0).narrow(0, 0, k + 1);
        let g = Self::value(&self.gamma);
        let u = match direction {
            Direction::Increasing => g.powi_scalar(2),
            Direction::Decreasing => g.powi_scalar(2).neg(),
            Direction::None => g,
        };
        let gate = sigmoid(alpha.matmul(row(u, k + 1)) + row(Self::value(&self.beta), k + 1));
        let pi = gate * row(p, k + 1);
        let y = state.matmul(row(Self::value(&self.omega).exp(), k));
        let c = row(Self::value(&self.c), k);
        let y2 = y.clone().powi_scalar(2);
        let near = y2.clone().lower_elem(0.01);
        let safe = y.clone().mask_fill(near.clone(), 1.0);
        let direct = safe.clone().tanh() / safe;
        let series = y2
            .clone()
            .mul_scalar(-17.0 / 315.0)
            .add_scalar(2.0 / 15.0)
            .mul(y2.clone())
            .add_scalar(-1.0 / 3.0)
            .mul(y2)
            .add_scalar(1.0);
        let ratio = direct.mask_where(near, series);
        let h = ratio * (c.clone().tanh() * (y + c).tanh()).neg().add_scalar(1.0);
        let units = (pi.clone().narrow(1, 1, k) * h).sum_dim(1);
        let mix = pi.narrow(1, 0, 1) + units;
        let _ = n;
        mix.mul_scalar(spec.s_max - spec.s_min)
            .add_scalar(spec.s_min)
    }
}

fn plain(device: &Device) -> Device {
    // Gradients and flat copies live on the device without autodiff.
    let _ = device;
    Device::flex()
}

fn tensor1(v: &[f32], device: &Device) -> Tensor<1> {
    Tensor::<1>::from_data(TensorData::new(v.to_vec(), [v.len()]), device)
}

/// `[out][in]` row-major to burn's `[in, out]`.
fn weight_tensor(rows: &[f32], out: usize, inp: usize, device: &Device) -> Tensor<2> {
    Tensor::<2>::from_data(TensorData::new(rows.to_vec(), [out, inp]), device).transpose()
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap_or_default()
}

impl MlpNet {
    /// Builds from flat nemm-core weights.
    pub(crate) fn from_flat(s: &ScalerWeights<f32>, device: &Device) -> Self {
        let layout = s.layout();
        assert_eq!(layout.len(), s.w.len(), "scaler weight count");
        let h = s.hidden;
        let blocks = (0..s.layers)
            .map(|l| {
                let r = layout.layer(l).expect("layer of the layout");
                let mut norm: LayerNorm = LayerNormConfig::new(h).init(device);
                norm.gamma = Param::from_tensor(tensor1(&s.w[r.gamma], device));
                norm.beta = Some(Param::from_tensor(tensor1(&s.w[r.beta], device)));
                Block {
                    linear: Linear {
                        weight: Param::from_tensor(weight_tensor(&s.w[r.w], h, r.fan_in, device)),
                        bias: Some(Param::from_tensor(tensor1(&s.w[r.b], device))),
                    },
                    norm,
                    act: LeakyRelu {
                        negative_slope: LEAKY_RELU_SLOPE as f64,
                    },
                }
            })
            .collect();
        let (wo, bo) = layout.output().expect("an MLP with layers");
        let branch = layout.branch_ranges().map(|r| {
            let p = |range| Param::from_tensor(tensor1(&s.w[range], device));
            BranchNet {
                r: (!r.r.is_empty()).then(|| p(r.r.clone())),
                theta_u: p(r.theta_u),
                c: p(r.c),
                theta_v: p(r.theta_v),
            }
        });
        Self {
            blocks,
            out: Linear {
                weight: Param::from_tensor(weight_tensor(&s.w[wo], 1, h, device)),
                bias: Some(Param::from_tensor(tensor1(&s.w[bo..bo + 1], device))),
            },
            branch,
        }
    }

    /// nemm-core's layout of this scaler's flat weights (`Self::to_flat`).
    pub fn layout(&self) -> nemm_kernels::mlp::ScalerLayout {
        let [inputs, hidden] = self
            .blocks
            .first()
            .map_or([0, 0], |b| b.linear.weight.val().dims());
        let branch = self
            .branch
            .as_ref()
            .map(|b| nemm_kernels::mlp::BranchLayout {
                state_inputs: usize::from(b.r.is_some()),
                units: b.theta_u.val().dims()[0],
            });
        nemm_kernels::mlp::ScalerLayout::mlp(inputs, hidden, self.blocks.len()).with_branch(branch)
    }

    /// Flat nemm-core weights.
    pub(crate) fn to_flat(&self) -> Vec<f32> {
        let layout = self.layout();
        let mut v = vec![0.0f32; layout.len()];
        let mut put = |range: std::ops::Range<usize>, vals: Vec<f32>| {
            v[range].copy_from_slice(&vals);
        };
        for (l, b) in self.blocks.iter().enumerate() {
            let r = layout.layer(l).expect("layer of the layout");
            put(r.w, to_vec(b.linear.weight.val().transpose()));
            if let Some(bias) = &b.linear.bias {
                put(r.b, to_vec(bias.val()));
            }
            put(r.gamma, to_vec(b.norm.gamma.val()));
            if let Some(beta) = &b.norm.beta {
                put(r.beta, to_vec(beta.val()));
            }
        }
        let (wo, bo) = layout.output().expect("an MLP with layers");
        put(wo, to_vec(self.out.weight.val().transpose()));
        if let Some(bias) = &self.out.bias {
            put(bo..bo + 1, to_vec(bias.val()));
        }
        if let (Some(b), Some(r)) = (&self.branch, layout.branch_ranges()) {
            if let Some(p) = &b.r {
                put(r.r, to_vec(p.val()));
            }
            put(r.theta_u, to_vec(b.theta_u.val()));
            put(r.c, to_vec(b.c.val()));
            put(r.theta_v, to_vec(b.theta_v.val()));
        }
        v
    }

    /// Raw output `z` for normalised inputs `[batch, inputs]` (alpha last): `[batch, 1]`.
    /// With an alpha branch the MLP gets its alpha column at zero and the branch adds
    /// `sum_k v_k leaky_relu(r_k x + u_k alpha_n + c_k)`.
    pub(crate) fn forward_raw(&self, x: Tensor<2>, spec: &ScalerSpec) -> Tensor<2> {
        let (Some(b), Some(shape)) = (&self.branch, &spec.branch) else {
            return self.mlp_raw(x);
        };
        let [_, d] = x.dims();
        let device = x.device();
        let alpha = x.clone().narrow(1, d - 1, 1);
        let mut mask = vec![1.0f32; d];
        mask[d - 1] = 0.0;
        let mask = Tensor::<2>::from_data(TensorData::new(mask, [1, d]), &device);
        let z = self.mlp_raw(x.clone() * mask);
        let k = shape.units;
        let row = |t: Tensor<1>| t.reshape([1, k]);
        let u = row(b
            .theta_u
            .val()
            .powi_scalar(2)
            .mul_scalar(shape.direction.sign()));
        let mut pre = alpha.matmul(u) + row(b.c.val());
        if let Some(r) = &b.r {
            pre = pre + x.narrow(1, 0, 1).matmul(row(r.val()));
        }
        let v = b.theta_v.val().powi_scalar(2).reshape([k, 1]);
        z + leaky_relu(pre, LEAKY_RELU_SLOPE as f64).matmul(v)
    }

    /// The MLP's raw output for inputs `[batch, inputs]`: `[batch, 1]`.
    fn mlp_raw(&self, x: Tensor<2>) -> Tensor<2> {
        let mut h = x;
        for b in &self.blocks {
            h = b.act.forward(b.norm.forward(b.linear.forward(h)));
        }
        self.out.forward(h)
    }

    /// Scale factor `s_min + (s_max - s_min) sigmoid(z)`: `[batch, 1]`.
    pub(crate) fn forward_scale(&self, x: Tensor<2>, spec: &ScalerSpec) -> Tensor<2> {
        sigmoid(self.forward_raw(x, spec))
            .mul_scalar(spec.s_max - spec.s_min)
            .add_scalar(spec.s_min)
    }

    /// Sum of squared weights of the MLP's linear maps (`||W||^2` of eq. 23; biases,
    /// LayerNorm parameters and the alpha branch are not regularised: the branch's slopes
    /// `theta_u^2 theta_v^2` are fourth order in its weights, so an L2 pull would hold them
    /// at zero, where their data gradient vanishes, and the learned coefficients would not
    /// move with alpha).
    pub(crate) fn weight_sq_sum(&self) -> Tensor<1> {
        let mut total = self.out.weight.val().powi_scalar(2).sum();
        for b in &self.blocks {
            total = total + b.linear.weight.val().powi_scalar(2).sum();
        }
        total
    }

    /// Adds a flat gradient (nemm-core layout, [`Self::layout`]) to the parameters' entries
    /// in `gp`.
    pub(crate) fn add_flat_grads(&self, g: &[f32], gp: &mut GradientsParams, device: &Device) {
        let dev = plain(device);
        let layout = self.layout();
        let h = layout.hidden;
        let add1 = |gp: &mut GradientsParams, p: &Param<Tensor<1>>, v: &[f32]| {
            let t = tensor1(v, &dev);
            let t = match gp.remove::<1>(p.id) {
                Some(old) => old + t,
                None => t,
            };
            gp.register(p.id, t);
        };
        let add2 =
            |gp: &mut GradientsParams, p: &Param<Tensor<2>>, v: &[f32], out: usize, inp: usize| {
                let t = weight_tensor(v, out, inp, &dev);
                let t = match gp.remove::<2>(p.id) {
                    Some(old) => old + t,
                    None => t,
                };
                gp.register(p.id, t);
            };
        for (l, b) in self.blocks.iter().enumerate() {
            let r = layout.layer(l).expect("layer of the layout");
            add2(gp, &b.linear.weight, &g[r.w], h, r.fan_in);
            if let Some(bias) = &b.linear.bias {
                add1(gp, bias, &g[r.b]);
            }
            add1(gp, &b.norm.gamma, &g[r.gamma]);
            if let Some(beta) = &b.norm.beta {
                add1(gp, beta, &g[r.beta]);
            }
        }
        let (wo, bo) = layout.output().expect("an MLP with layers");
        add2(gp, &self.out.weight, &g[wo], 1, h);
        if let Some(bias) = &self.out.bias {
            add1(gp, bias, &g[bo..bo + 1]);
        }
        if let (Some(b), Some(r)) = (&self.branch, layout.branch_ranges()) {
            if let Some(p) = &b.r {
                add1(gp, p, &g[r.r]);
            }
            add1(gp, &b.theta_u, &g[r.theta_u]);
            add1(gp, &b.c, &g[r.c]);
            add1(gp, &b.theta_v, &g[r.theta_v]);
        }
    }
}

/// The constants are stored as `ln(c) / LOG_CONSTANT_SCALE`: Adam moves every parameter by
/// about the learning rate per step, so this makes the four constants move
/// `LOG_CONSTANT_SCALE` times faster in log space (5 % per step at lr 5e-3) than the scaler
/// weights, which need small steps, while the constants must be able to travel by factors.
pub(crate) const LOG_CONSTANT_SCALE: f32 = 10.0;

/// The lost-motion element's parameters are stored as `ln(v) / LOG_LOST_MOTION_SCALE`: the
/// travels must grow by factors of ten from their start (a tenth of the liquid spring's
/// deflection) within the few hundred steps of the Linear EMM stage, so they move three
/// times faster than the constants (15 % per step at lr 5e-3).
pub(crate) const LOG_LOST_MOTION_SCALE: f32 = 30.0;

/// Adds `d` to the gradient of parameter `id` in `gp` (registers it if there is none).
fn add_grad(gp: &mut GradientsParams, id: burn::module::ParamId, d: Tensor<1>) {
    let d = match gp.remove::<1>(id) {
        Some(old) => old + d,
        None => d,
    };
    gp.register(id, d);
}

/// All trainable parameters of an EMM-family model.
#[derive(Module, Debug)]
pub struct EmmNet {
    /// `[ln b_fl,ini, ln b_pr,ini, ln k_pr,ini, ln T_pr] / LOG_CONSTANT_SCALE` (SI units
    /// inside the log).
    pub(crate) log_c: Param<Tensor<1>>,
    /// `b_fl(v_st, alpha)` scaler.
    pub b_fl: Option<ScalerNet>,
    /// `b_pr(alpha)` scaler.
    pub b_pr: Option<ScalerNet>,
    /// `k_pr(x_pr, alpha)` scaler.
    pub k_pr: Option<ScalerNet>,
    /// The static force's trained parameters (order of `nemm_core::StaticForce::params`),
    /// each divided by its unit ([`StaticFrame::units`]); the last, `F_c`, enters as its
    /// absolute value, so that `F_c >= 0`.
    pub static_force: Option<Param<Tensor<1>>>,
    /// The lost-motion element's parameters (order of `nemm_core::LostMotion::params`),
    /// stored as `ln(v) / LOG_LOST_MOTION_SCALE` (SI units inside the log):
    /// every value stays positive, so the travels grow with alpha by construction.
    pub lost_motion: Option<Param<Tensor<1>>>,
}

/// What is fixed during training: integration, normalisation, scaler shapes and bounds.
#[derive(Debug, Clone, PartialEq)]
pub struct NetFrame {
    /// Integrator.
    pub integrator: nemm_core::Integrator,
    /// Step \[s\].
    pub dt: f32,
    /// Velocity scale \[m/s\].
    pub(crate) v_scale: f32,
    /// `x_pr` scale \[m\].
    pub(crate) x_scale: f32,
    /// Alpha scale.
    pub(crate) alpha_scale: f32,
    /// `b_fl` scaler spec.
    pub b_fl: Option<ScalerSpec>,
    /// `b_pr` scaler spec.
    pub b_pr: Option<ScalerSpec>,
    /// `k_pr` scaler spec.
    pub k_pr: Option<ScalerSpec>,
    /// Declared monotonicity priors in alpha.
    pub priors: Priors,
    /// The static force's fixed part, if the model has one.
    pub static_force: Option<StaticFrame>,
}

/// The fixed part of a static force in training.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticFrame {
    /// Reference position `x_ref` \[m\].
    pub x_ref: f32,
    /// Smoothing velocity `v_c` \[m/s\].
    pub(crate) v_c: f32,
    /// Physical value of one unit of each trained parameter (`static_units`).
    pub units: [f32; STATIC_PARAMS],
}

/// Fraction of the force scale by which one unit of a static-force parameter moves the
/// force: Adam moves a parameter by about the learning rate per step, so at 5e-3 and a
/// 2000 N force scale a step moves the gas offset and the friction by about 1 N.
pub(crate) const STATIC_UNIT: f32 = 0.1;

/// Units of the static-force parameters: [`STATIC_UNIT`] times the force scale \[N\] for
/// the forces, that divided by the span of `x - x_ref` \[m\] for the gas springs.
pub(crate) fn static_units(force_scale_n: f32, x_span_m: f32) -> [f32; STATIC_PARAMS] {
    let f = STATIC_UNIT * force_scale_n;
    let k = f / x_span_m.max(1e-6);
    [f, f, k, k, f]
}

fn spec_of(s: &Option<ScalerWeights<f32>>) -> Option<ScalerSpec> {
    s.as_ref().map(|s| ScalerSpec {
        inputs: s.inputs,
        hidden: s.hidden,
        layers: s.layers,
        s_min: s.s_min,
        s_max: s.s_max,
        branch: s.branch,
        cumulative: s.cumulative,
    })
}

impl EmmNet {
    /// The module and frame of rollout parameters; a static force is trained in `units`
    /// (`static_units`; `None`: the default of `static_units` at a 1 kN force scale and a
    /// 0.1 m span).
    pub fn from_rollout(
        p: &RolloutParams<f32>,
        units: Option<[f32; STATIC_PARAMS]>,
        device: &Device,
    ) -> (Self, NetFrame) {
        let units = units.unwrap_or_else(|| static_units(1000.0, 0.1));
        let c = [p.b_fl0, p.b_pr0, p.k0, p.t_pr].map(|v| v.ln() / LOG_CONSTANT_SCALE);
        let net = Self {
            log_c: Param::from_tensor(tensor1(&c, device)),
            b_fl: p.b_fl.as_ref().map(|s| ScalerNet::from_flat(s, device)),
            b_pr: p.b_pr.as_ref().map(|s| ScalerNet::from_flat(s, device)),
            k_pr: p.k_pr.as_ref().map(|s| ScalerNet::from_flat(s, device)),
            static_force: p.static_force.as_ref().map(|s| {
                let t: Vec<f32> = (0..STATIC_PARAMS).map(|q| s.theta[q] / units[q]).collect();
                Param::from_tensor(tensor1(&t, device))
            }),
            lost_motion: p.lost_motion.as_ref().map(|l| {
                let t: Vec<f32> = l.iter().map(|v| v.ln() / LOG_LOST_MOTION_SCALE).collect();
                Param::from_tensor(tensor1(&t, device))
            }),
        };
        let frame = NetFrame {
            integrator: p.integrator,
            dt: p.dt,
            v_scale: p.v_scale,
            x_scale: p.x_scale,
            alpha_scale: p.alpha_scale,
            b_fl: spec_of(&p.b_fl),
            b_pr: spec_of(&p.b_pr),
            k_pr: spec_of(&p.k_pr),
            priors: p.priors,
            static_force: p.static_force.as_ref().map(|s| StaticFrame {
                x_ref: s.x_ref,
                v_c: s.v_c,
                units,
            }),
        };
        (net, frame)
    }

    /// The constants `[b_fl,ini, b_pr,ini, k_pr,ini, T_pr]` in SI units.
    pub fn constants(&self) -> [f32; 4] {
        let v = to_vec(self.log_c.val());
        let g = |i: usize| (v.get(i).copied().unwrap_or(f32::NAN) * LOG_CONSTANT_SCALE).exp();
        [g(0), g(1), g(2), g(3)]
    }

    /// The module with the constants `c` (`[b_fl,ini, b_pr,ini, k_pr,ini, T_pr]` in SI
    /// units, positive). The parameter keeps its id, so the optimizer's moments stay
    /// attached to it.
    pub(crate) fn with_constants(self, c: [f32; 4]) -> Self {
        let stored: Vec<f32> = c.iter().map(|v| v.ln() / LOG_CONSTANT_SCALE).collect();
        let log_c = self.log_c.map(|t| {
            let grad = t.is_require_grad();
            Tensor::<1>::from_data(TensorData::new(stored, [4]), &t.device()).set_require_grad(grad)
        });
        Self { log_c, ..self }
    }

    /// Flat rollout parameters.
    pub fn to_rollout(&self, f: &NetFrame) -> RolloutParams<f32> {
        let [b_fl0, b_pr0, k0, t_pr] = self.constants();
        let flat = |n: &Option<ScalerNet>, s: &Option<ScalerSpec>| match (n, s) {
            (Some(n), Some(s)) => Some(ScalerWeights {
                inputs: s.inputs,
                hidden: s.hidden,
                layers: s.layers,
                w: n.to_flat(),
                s_min: s.s_min,
                s_max: s.s_max,
                branch: s.branch,
                cumulative: s.cumulative,
            }),
            _ => None,
        };
        RolloutParams {
            integrator: f.integrator,
            dt: f.dt,
            b_fl0,
            b_pr0,
            k0,
            t_pr,
            v_scale: f.v_scale,
            x_scale: f.x_scale,
            alpha_scale: f.alpha_scale,
            b_fl: flat(&self.b_fl, &f.b_fl),
            b_pr: flat(&self.b_pr, &f.b_pr),
            k_pr: flat(&self.k_pr, &f.k_pr),
            priors: f.priors,
            static_force: self
                .static_force
                .as_ref()
                .zip(f.static_force)
                .map(|(t, sf)| {
                    let v = to_vec(t.val());
                    let theta: [f32; STATIC_PARAMS] = std::array::from_fn(|q| {
                        let x = v.get(q).copied().unwrap_or(f32::NAN) * sf.units[q];
                        if q == STATIC_PARAMS - 1 {
                            x.abs()
                        } else {
                            x
                        }
                    });
                    StaticParams {
                        theta,
                        x_ref: sf.x_ref,
                        v_c: sf.v_c,
                    }
                }),
            lost_motion: self.lost_motion_params(),
        }
    }

    /// The lost-motion element's parameters in SI units, if the model has one.
    pub(crate) fn lost_motion_params(&self) -> Option<[f32; LOST_MOTION_PARAMS]> {
        self.lost_motion.as_ref().map(|t| {
            let v = to_vec(t.val());
            std::array::from_fn(|q| {
                (v.get(q).copied().unwrap_or(f32::NAN) * LOG_LOST_MOTION_SCALE).exp()
            })
        })
    }

    /// Adds the rollout gradient (`dL/dc` for the constants, chain-ruled to the stored
    /// `ln(c) / LOG_CONSTANT_SCALE`: `LOG_CONSTANT_SCALE c dL/dc`; flat scaler gradients) to
    /// `gp`. `train_constants` selects which constants
    /// receive a gradient (`[b_fl, b_pr, k_pr, T_pr]`).
    pub(crate) fn add_rollout_grads(
        &self,
        frame: &NetFrame,
        g: &RolloutGrads<f32>,
        train_constants: [bool; 4],
        gp: &mut GradientsParams,
        device: &Device,
    ) {
        let dev = plain(device);
        let c = self.constants();
        let dc = [g.b_fl0, g.b_pr0, g.k0, g.t_pr];
        let dlog: Vec<f32> = (0..4)
            .map(|i| {
                if train_constants[i] {
                    LOG_CONSTANT_SCALE * c[i] * dc[i]
                } else {
                    0.0
                }
            })
            .collect();
        add_grad(gp, self.log_c.id, tensor1(&dlog, &dev));
        for (net, flat) in [
            (&self.b_fl, &g.b_fl),
            (&self.b_pr, &g.b_pr),
            (&self.k_pr, &g.k_pr),
        ] {
            if let Some(n) = net {
                n.add_flat_grads(flat, gp, device);
            }
        }
        if let (Some(t), Some(sf), Some(fr)) = (
            &self.static_force,
            g.static_force.get(..STATIC_PARAMS),
            frame.static_force,
        ) {
            let v = to_vec(t.val());
            // d theta_q / d raw_q = unit_q, times sign(raw) for |raw| of F_c.
            let d: Vec<f32> = (0..STATIC_PARAMS)
                .map(|q| {
                    let negative = q == STATIC_PARAMS - 1 && v.get(q).is_some_and(|&r| r < 0.0);
                    let sign = if negative { -1.0 } else { 1.0 };
                    sf[q] * fr.units[q] * sign
                })
                .collect();
            add_grad(gp, t.id, tensor1(&d, &dev));
        }
        if let (Some(t), Some(v), Some(gl)) = (
            &self.lost_motion,
            self.lost_motion_params(),
            g.lost_motion.get(..LOST_MOTION_PARAMS),
        ) {
            // v = exp(LOG_LOST_MOTION_SCALE raw): dL/draw = LOG_LOST_MOTION_SCALE v dL/dv.
            let d: Vec<f32> = (0..LOST_MOTION_PARAMS)
                .map(|q| LOG_LOST_MOTION_SCALE * v[q] * gl[q])
                .collect();
            add_grad(gp, t.id, tensor1(&d, &dev));
        }
    }

    /// The regularisation term of eq. 24, `sum_i ||W_i||_2`: for every scaler the Euclidean
    /// norm (not squared, as the paper writes it) of all its linear weights. Its gradient per
    /// weight, `lambda w / ||W||`, stays small next to the data term, whereas a squared norm
    /// with `lambda = 1e-3` would out-weigh a normalised MSE of ~1e-3 and shrink the scalers
    /// to constants. A cumulative scaler has no linear maps and is left out (its scale is
    /// bounded and its force monotone by construction).
    pub(crate) fn l2_norms(&self, device: &Device) -> Tensor<1> {
        let mut total = Tensor::<1>::zeros([1], device);
        for n in [&self.b_fl, &self.b_pr, &self.k_pr].into_iter().flatten() {
            if let Some(sq) = n.weight_sq_sum() {
                total = total + sq.add_scalar(1e-12).sqrt();
            }
        }
        total
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::params::from_core;
    use nemm_core::testing::example_model;
    use nemm_core::ModelKind;

    #[test]
    fn flat_round_trip_and_forward_match_core() {
        let device = Device::flex();
        let m = example_model(ModelKind::Nemm, 8, 3).expect("model");
        let p: RolloutParams<f32> = from_core(&m).expect("emm");
        let (net, frame) = EmmNet::from_rollout(&p, None, &device);
        let q = net.to_rollout(&frame);
        assert_eq!(q.b_fl.as_ref().map(|s| &s.w), p.b_fl.as_ref().map(|s| &s.w));
        assert_eq!(q.k_pr.as_ref().map(|s| &s.w), p.k_pr.as_ref().map(|s| &s.w));
        assert!((q.k0 - p.k0).abs() <= 1e-6 * p.k0);
        // burn's forward equals nemm-core's reference forward.
        let spec = frame.b_fl.expect("spec");
        let b = net.b_fl.as_ref().expect("b_fl");
        let xs = [[0.3f32, 0.5], [-0.9, 0.0], [1.1, 1.0]];
        let x = Tensor::<2>::from_data(
            TensorData::new(xs.iter().flatten().copied().collect::<Vec<f32>>(), [3, 2]),
            &device,
        );
        let s = to_vec(b.forward_scale(x, &spec));
        let core = match &m.body {
            nemm_core::Body::Nemm { b_fl, .. } => b_fl,
            _ => unreachable!(),
        };
        for (i, x) in xs.iter().enumerate() {
            let r = core.scale(x).expect("scale");
            assert!((s[i] - r).abs() < 1e-5, "{} vs {}", s[i], r);
        }
    }

    /// With alpha branches: the flat round trip keeps the branch weights (nemm-core's
    /// layout) and burn's forward equals nemm-core's reference (`ScalerView::raw` through
    /// `Model::b_fl`, `Model::b_pr`) for a scaler with a state input and one of alpha alone.
    #[test]
    fn branched_scalers_round_trip_and_match_core() {
        use crate::train::pipeline::with_branch;
        use nemm_kernels::mlp::Direction;
        let device = Device::flex();
        let m = example_model(ModelKind::Nemm, 8, 3).expect("model");
        let mut p: RolloutParams<f32> = from_core(&m).expect("emm");
        p.b_fl = p
            .b_fl
            .take()
            .map(|s| with_branch(s, Direction::Decreasing, 1, 4, 7));
        p.b_pr = p
            .b_pr
            .take()
            .map(|s| with_branch(s, Direction::Decreasing, 0, 3, 8));
        let (net, frame) = EmmNet::from_rollout(&p, None, &device);
        let q = net.to_rollout(&frame);
        assert_eq!(q.b_fl.as_ref().map(|s| &s.w), p.b_fl.as_ref().map(|s| &s.w));
        assert_eq!(q.b_pr.as_ref().map(|s| &s.w), p.b_pr.as_ref().map(|s| &s.w));
        let core = crate::train::params::to_core(&p, m.meta).expect("valid model");
        let (vs, al) = (p.v_scale, p.alpha_scale);
        let pts = [(0.3f32, 0.1f32), (-0.9, 0.0), (1.1, 0.9), (0.05, 0.45)];
        let col = |v: Vec<f32>, d: usize| {
            let n = v.len() / d;
            Tensor::<2>::from_data(TensorData::new(v, [n, d]), &device)
        };
        let (nb, sb) = (net.b_fl.as_ref().expect("b_fl"), frame.b_fl.expect("spec"));
        let x = col(pts.iter().flat_map(|&(v, a)| [v / vs, a / al]).collect(), 2);
        let s = to_vec(nb.forward_scale(x, &sb));
        for (i, &(v, a)) in pts.iter().enumerate() {
            let want = core.b_fl(v, a).expect("b_fl") / p.b_fl0;
            assert!(
                (s[i] - want).abs() < 1e-5 * want.abs().max(1.0),
                "b_fl {i}: {} vs {want}",
                s[i]
            );
        }
        let (nb, sb) = (net.b_pr.as_ref().expect("b_pr"), frame.b_pr.expect("spec"));
        let x = col(pts.iter().map(|&(_, a)| a / al).collect(), 1);
        let s = to_vec(nb.forward_scale(x, &sb));
        for (i, &(_, a)) in pts.iter().enumerate() {
            let want = core.b_pr(a).expect("b_pr") / p.b_pr0;
            assert!(
                (s[i] - want).abs() < 1e-5 * want.abs().max(1.0),
                "b_pr {i}: {} vs {want}",
                s[i]
            );
        }
    }
}
