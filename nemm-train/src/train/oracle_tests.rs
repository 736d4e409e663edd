//! The adjoint against burn's autodiff: the same rollout written with burn tensor ops,
//! differentiated by burn's tape (feasible only for short windows), gives the reference.
use super::adjoint::{loss_and_grad, Grid, RolloutGrads, RolloutParams, Window};
use super::net::{EmmNet, NetFrame, ScalerNet};
use super::params::from_core;
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor, TensorData};
use nemm_core::testing::example_model;
use nemm_core::{Integrator, ModelKind};

fn t1(v: Vec<f32>, device: &Device) -> Tensor<1> {
    let n = v.len();
    Tensor::<1>::from_data(TensorData::new(v, [n]), device)
}

fn col(t: &Tensor<1>) -> Tensor<2> {
    let n = t.dims()[0];
    t.clone().reshape([n, 1])
}

/// Coefficient `c0 * s(state / scale, alpha_n)` over the batch, or `c0` broadcast.
fn coef(
    c0: &Tensor<1>,
    net: &Option<ScalerNet>,
    spec: &Option<super::net::ScalerSpec>,
    state: &Tensor<1>,
    scale: f32,
    alpha_n: &Tensor<1>,
) -> Tensor<1> {
    let b = state.dims()[0];
    match (net, spec) {
        (Some(n), Some(s)) => {
            let x = Tensor::cat(vec![col(&state.clone().div_scalar(scale)), col(alpha_n)], 1);
            n.forward_scale(x, s).reshape([b]) * c0.clone()
        }
        _ => c0.clone().expand([b]),
    }
}

/// Loss of the rollout in burn ops (same semantics as the adjoint).
#[allow(clippy::too_many_arguments)]
fn burn_loss(
    net: &EmmNet,
    f: &NetFrame,
    us: &[Vec<f32>],
    fs: &[Vec<f32>],
    alphas: &[f32],
    warmup: usize,
    force_scale: f32,
    device: &Device,
) -> Tensor<1> {
    let b = us.len();
    let n = us[0].len();
    let logc = net.log_c.val();
    let c = |i: usize| {
        logc.clone()
            .narrow(0, i, 1)
            .mul_scalar(super::net::LOG_CONSTANT_SCALE)
            .exp()
    };
    let (b_fl0, b_pr0, k0, t_pr) = (c(0), c(1), c(2), c(3));
    let alpha_n = t1(alphas.iter().map(|a| a / f.alpha_scale).collect(), device);
    let bp = match (&net.b_pr, &f.b_pr) {
        (Some(nn), Some(s)) => nn.forward_scale(col(&alpha_n), s).reshape([b]) * b_pr0.clone(),
        _ => b_pr0.clone().expand([b]),
    };
    let it = t_pr.recip();
    let coeffs = |x: &Tensor<1>, v: &Tensor<1>| {
        (
            coef(&b_fl0, &net.b_fl, &f.b_fl, v, f.v_scale, &alpha_n),
            coef(&k0, &net.k_pr, &f.k_pr, x, f.x_scale, &alpha_n),
        )
    };
    let q = |bf: &Tensor<1>, k: &Tensor<1>, x: &Tensor<1>, u: &Tensor<1>| {
        (k.clone() * x.clone() + bp.clone() * u.clone()) / (bp.clone() + bf.clone())
    };
    let rhs = |x: &Tensor<1>, v: &Tensor<1>, u: &Tensor<1>| {
        let (bf, k) = coeffs(x, v);
        let qq = q(&bf, &k, x, u);
        (u.clone() - qq.clone(), (qq - v.clone()) * it.clone())
    };
    let dt = f.dt;
    let mut x = Tensor::<1>::zeros([b], device);
    let mut v = Tensor::<1>::zeros([b], device);
    let mut u_prev = Tensor::<1>::zeros([b], device);
    let mut loss = Tensor::<1>::zeros([1], device);
    for i in 0..n {
        let u1 = t1(us.iter().map(|u| u[i]).collect(), device);
        let um = (u_prev.clone() + u1.clone()).mul_scalar(0.5);
        let (k1x, k1v) = rhs(&x, &v, &u_prev);
        let (x2, v2) = (
            x.clone() + k1x.clone().mul_scalar(dt / 2.0),
            v.clone() + k1v.clone().mul_scalar(dt / 2.0),
        );
        let (k2x, k2v) = rhs(&x2, &v2, &um);
        let (nx, nv) = match f.integrator {
            Integrator::Rk4 => {
                let (x3, v3) = (
                    x.clone() + k2x.clone().mul_scalar(dt / 2.0),
                    v.clone() + k2v.clone().mul_scalar(dt / 2.0),
                );
                let (k3x, k3v) = rhs(&x3, &v3, &um);
                let (x4, v4) = (
                    x.clone() + k3x.clone().mul_scalar(dt),
                    v.clone() + k3v.clone().mul_scalar(dt),
                );
                let (k4x, k4v) = rhs(&x4, &v4, &u1);
                (
                    x.clone() + (k1x + k4x + (k2x + k3x).mul_scalar(2.0)).mul_scalar(dt / 6.0),
                    v.clone() + (k1v + k4v + (k2v + k3v).mul_scalar(2.0)).mul_scalar(dt / 6.0),
                )
            }
            Integrator::Rk3 => {
                let x3 = x.clone() + (k2x.clone().mul_scalar(2.0) - k1x.clone()).mul_scalar(dt);
                let v3 = v.clone() + (k2v.clone().mul_scalar(2.0) - k1v.clone()).mul_scalar(dt);
                let (k3x, k3v) = rhs(&x3, &v3, &u1);
                (
                    x.clone() + (k1x + k3x + k2x.mul_scalar(4.0)).mul_scalar(dt / 6.0),
                    v.clone() + (k1v + k3v + k2v.mul_scalar(4.0)).mul_scalar(dt / 6.0),
                )
            }
        };
        x = nx;
        v = nv;
        if i >= warmup {
            let (bf, k) = coeffs(&x, &v);
            let y = bf.clone() * q(&bf, &k, &x, &u1);
            let fm = t1(fs.iter().map(|f| f[i]).collect(), device);
            loss = loss
                + (y - fm)
                    .div_scalar(force_scale)
                    .powi_scalar(2)
                    .sum()
                    .reshape([1]);
        }
        u_prev = u1;
    }
    loss.div_scalar((b * (n - warmup)) as f32)
}

/// Burn's parameter gradients, flattened like [`RolloutGrads`] (constants as `dL/dc`).
fn flat_grads(net: &EmmNet, gp: &GradientsParams) -> RolloutGrads<f32> {
    let v1 = |p: &burn::module::Param<Tensor<1>>| {
        gp.get::<1>(p.id)
            .map(|t| {
                t.into_data()
                    .convert::<f32>()
                    .try_into_vec::<f32>()
                    .unwrap_or_default()
            })
            .unwrap_or_else(|| vec![0.0; p.val().dims()[0]])
    };
    let v2 = |p: &burn::module::Param<Tensor<2>>| {
        let [i, o] = p.val().dims();
        gp.get::<2>(p.id)
            .map(|t| {
                t.transpose()
                    .into_data()
                    .convert::<f32>()
                    .try_into_vec::<f32>()
                    .unwrap_or_default()
            })
            .unwrap_or_else(|| vec![0.0; i * o])
    };
    let scaler = |n: &Option<ScalerNet>| -> Vec<f32> {
        let n = match n {
            None => return Vec::new(),
            Some(ScalerNet::Cumulative(c)) => {
                // Stored divided by the scale: dL/dw = dL/dstored / scale.
                return [&c.a, &c.omega, &c.c, &c.gamma, &c.beta]
                    .into_iter()
                    .flat_map(v1)
                    .map(|g| g / super::net::CUMULATIVE_PARAM_SCALE)
                    .collect();
            }
            Some(ScalerNet::Mlp(n)) => n,
        };
        let mut out = Vec::new();
        for b in &n.blocks {
            out.extend(v2(&b.linear.weight));
            out.extend(v1(b.linear.bias.as_ref().expect("bias")));
            out.extend(v1(&b.norm.gamma));
            out.extend(v1(b.norm.beta.as_ref().expect("beta")));
        }
        out.extend(v2(&n.out.weight));
        out.extend(v1(n.out.bias.as_ref().expect("bias")));
        out
    };
    let dlog = v1(&net.log_c);
    let c = net.constants();
    let k = super::net::LOG_CONSTANT_SCALE;
    RolloutGrads {
        b_fl0: dlog[0] / (k * c[0]),
        b_pr0: dlog[1] / (k * c[1]),
        k0: dlog[2] / (k * c[2]),
        t_pr: dlog[3] / (k * c[3]),
        b_fl: scaler(&net.b_fl),
        b_pr: scaler(&net.b_pr),
        k_pr: scaler(&net.k_pr),
        static_force: Vec::new(),
        lost_motion: Vec::new(),
    }
}

fn check(kind: ModelKind, integ: Integrator) {
    check_model(example_model(kind, 6, 3).expect("model"), kind, integ);
}

fn check_model(mut m: nemm_core::Model, kind: ModelKind, integ: Integrator) {
    let device = Device::flex().autodiff();
    m.integrator = integ;
    m.dt_s = 5e-4;
    let p: RolloutParams<f32> = from_core(&m).expect("emm");
    let (net, frame) = EmmNet::from_rollout(&p, None, &device);
    let n = 40;
    let warmup = 5;
    let nw = 5;
    let us: Vec<Vec<f32>> = (0..nw)
        .map(|w| {
            (0..n)
                .map(|i| 0.6 * ((i as f32) * 0.13 + w as f32).sin())
                .collect()
        })
        .collect();
    let fs: Vec<Vec<f32>> = (0..nw)
        .map(|w| {
            (0..n)
                .map(|i| 900.0 * ((i as f32) * 0.11 - w as f32).cos())
                .collect()
        })
        .collect();
    let alphas: Vec<f32> = (0..nw).map(|w| [0.0, 0.3, 0.15][w % 3]).collect();
    let fscale = 1500.0;
    let loss = burn_loss(&net, &frame, &us, &fs, &alphas, warmup, fscale, &device);
    let loss_burn = loss
        .clone()
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("loss")[0];
    let gp = GradientsParams::from_grads(loss.backward(), &net);
    let reference = flat_grads(&net, &gp);
    let wins: Vec<Window<'_>> = (0..nw)
        .map(|i| Window {
            u: &us[i],
            f: &fs[i],
            alpha: alphas[i],
            alphas: None,
            x: None,
        })
        .collect();
    let (loss_adj, g) = loss_and_grad(&p, &wins, &Grid::SAME, warmup, fscale as f64);
    assert!(
        ((loss_adj as f32) - loss_burn).abs() <= 1e-5 * loss_burn,
        "loss {loss_adj} vs burn {loss_burn}"
    );
    let groups: [(&str, Vec<f32>, Vec<f32>); 7] = [
        ("b_fl,ini", vec![g.b_fl0], vec![reference.b_fl0]),
        ("b_pr,ini", vec![g.b_pr0], vec![reference.b_pr0]),
        ("k_pr,ini", vec![g.k0], vec![reference.k0]),
        ("T_pr", vec![g.t_pr], vec![reference.t_pr]),
        ("b_fl scaler", g.b_fl.clone(), reference.b_fl.clone()),
        ("b_pr scaler", g.b_pr.clone(), reference.b_pr.clone()),
        ("k_pr scaler", g.k_pr.clone(), reference.k_pr.clone()),
    ];
    for (name, a, r) in groups {
        assert_eq!(a.len(), r.len(), "{name}: sizes");
        if a.is_empty() {
            continue;
        }
        let scale = r.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        let worst = a
            .iter()
            .zip(&r)
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs() / scale.max(1e-30)));
        eprintln!("{kind:?} {integ:?} {name}: max |adjoint - burn| / max|burn| = {worst:e}");
        assert!(
            worst <= 1e-4,
            "{kind:?} {integ:?} {name}: relative error {worst:e}"
        );
    }
}

#[test]
fn adjoint_matches_burn_autodiff_nemm_rk4() {
    check(ModelKind::Nemm, Integrator::Rk4);
}

#[test]
fn adjoint_matches_burn_autodiff_nemm_rk3() {
    check(ModelKind::Nemm, Integrator::Rk3);
}

#[test]
fn adjoint_matches_burn_autodiff_light_and_linear() {
    check(ModelKind::NemmLight, Integrator::Rk4);
    check(ModelKind::LinearEmm, Integrator::Rk4);
}

/// The cumulative scalers' burn forward (the quasi-static regression's and the penalty's)
/// and the kernels' reverse mode (the rollout adjoint's) agree.
#[test]
fn adjoint_matches_burn_autodiff_with_cumulative_scalers() {
    for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
        let m = nemm_core::testing::example_cumulative_model(kind);
        check_model(m, kind, Integrator::Rk4);
    }
}
