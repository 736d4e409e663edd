//! The alpha branch: monotone in alpha in the declared direction for any weights, the same
//! function in the reference, compiled and tabulated paths, carried by the weights format
//! and refused when corrupt.

mod common;

use common::blob_of;
use nemm_core::testing::{example_branch, example_model_with_branches};
use nemm_core::Sample;
use nemm_core::{
    decode, encode, Body, Condition, DecodeError, Estimator, EstimatorConfig, EvalMode, Model,
    TableConfig,
};
use nemm_core::{ModelError, Priors};
use nemm_kernels::mlp::{AlphaBranch, BranchError, CompiledScaler, Direction};
use proptest::prelude::*;

const P: usize = 1400;

fn priors(b_fl: Direction, b_pr: Direction, k_pr: Direction) -> Priors {
    Priors { b_fl, b_pr, k_pr }
}

fn direction() -> impl Strategy<Value = Direction> {
    prop_oneof![Just(Direction::Decreasing), Just(Direction::Increasing)]
}

/// `b_fl`, `b_pr`, `k_pr` at a state and an alpha, by the reference path.
fn coefficients(m: &Model<P>, x: f32, alpha: f32) -> [f32; 3] {
    [
        m.b_fl(x * m.scales.velocity_m_s, alpha).unwrap(),
        m.b_pr(alpha).unwrap(),
        m.k_pr(x * m.scales.x_pr_m, alpha).unwrap(),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// For random weights (MLP and branch) and random directions, every coefficient is
    /// monotone in alpha in its direction at every state of a grid, exactly in f32.
    #[test]
    fn coefficients_are_monotone_in_alpha_for_any_weights(
        d_fl in direction(), d_pr in direction(), d_k in direction(),
        units in 1u8..=32, hidden in prop_oneof![Just(4u8), Just(8), Just(16)],
        seed in 0u64..1000,
    ) {
        let mut m: Model<P> =
            example_model_with_branches(hidden, 3, units, priors(d_fl, d_pr, d_k)).unwrap();
        // Different weights per case: scramble the branches with the seed.
        let br = &mut m.alpha_branches;
        for (slot, dir, state, s) in [
            (&mut br.b_fl, d_fl, 1u8, 1u64),
            (&mut br.b_pr, d_pr, 0, 2),
            (&mut br.k_pr, d_k, 1, 3),
        ] {
            *slot = Some(example_branch(dir, state, units, seed * 7 + s).unwrap());
        }
        m.validate().unwrap();
        let dirs = [d_fl, d_pr, d_k];
        for ix in 0..=24 {
            let x = -1.2 + 0.1 * ix as f32;
            let mut prev: Option<[f32; 3]> = None;
            for ia in 0..=50 {
                let alpha = ia as f32 / 50.0;
                let c = coefficients(&m, x, alpha);
                if let Some(p) = prev {
                    for i in 0..3 {
                        match dirs[i] {
                            Direction::Decreasing => prop_assert!(c[i] <= p[i], "{i} {x} {alpha}: {} > {}", c[i], p[i]),
                            Direction::Increasing => prop_assert!(c[i] >= p[i], "{i} {x} {alpha}: {} < {}", c[i], p[i]),
                            Direction::None => {}
                        }
                    }
                }
                prev = Some(c);
            }
        }
    }
}

/// The compiled scaler with a branch (what the estimator runs) is the reference function
/// up to f32 rounding, at every alpha it is re-folded to.
#[test]
fn compiled_branch_matches_the_reference() {
    let m: Model<P> = example_model_with_branches(
        16,
        5,
        16,
        priors(
            Direction::Decreasing,
            Direction::Increasing,
            Direction::Decreasing,
        ),
    )
    .unwrap();
    let Body::Nemm { emm, b_fl, .. } = &m.body else {
        panic!("nemm")
    };
    let branch = m.alpha_branches.b_fl.as_ref();
    let sc = m.scales;
    let mut c = CompiledScaler::compile_with_branch(
        b_fl,
        branch,
        emm.b_fl_ns_per_m,
        sc.velocity_m_s,
        0.0,
        sc.alpha,
    )
    .unwrap();
    assert!(c.has_branch());
    for alpha in [0.0f32, 0.1, 0.15, 0.3, 0.7, 1.0] {
        c.set_alpha(alpha);
        for i in 0..=40 {
            let v = (-1.2 + 0.06 * i as f32) * sc.velocity_m_s;
            let reference = m.b_fl(v, alpha).unwrap();
            let got = c.eval(v);
            assert!(
                (got - reference).abs() <= 1e-5 * reference,
                "alpha {alpha}, v {v}: {got} vs {reference}"
            );
        }
    }
}

/// The estimator in table mode follows the exact mode on a branched model (the tables are
/// built from the compiled scalers with their branches), and both follow the reference
/// `b_pr(alpha)`.
#[test]
fn table_mode_matches_exact_mode_with_branches() {
    let m: Model<P> = example_model_with_branches(
        16,
        5,
        16,
        priors(
            Direction::Decreasing,
            Direction::Decreasing,
            Direction::Increasing,
        ),
    )
    .unwrap();
    for alpha in [0.0f32, 0.15, 0.3] {
        let mut exact: Estimator<P> = Estimator::new(&m, EstimatorConfig::new(alpha)).unwrap();
        let cfg = EstimatorConfig {
            mode: EvalMode::Table(TableConfig::new(1e-4)),
            ..EstimatorConfig::new(alpha)
        };
        let mut table: Estimator<P> = Estimator::new(&m, cfg).unwrap();
        assert!(table.table_accuracy().unwrap().max_rel_error <= 1e-4);
        let mut worst = 0.0f32;
        for k in 0..4000 {
            let t = k as f32 * m.dt_s;
            let v = 0.6 * (2.0 * std::f32::consts::PI * 7.0 * t).sin();
            let (a, b) = (
                exact.step(Sample::new(v)).unwrap().force_n,
                table.step(Sample::new(v)).unwrap().force_n,
            );
            worst = worst.max((a - b).abs());
        }
        assert!(
            worst <= 1e-3 * m.meta.force_scale_n,
            "alpha {alpha}: {worst} N"
        );
        let b_pr = m.b_pr(alpha).unwrap();
        assert!((exact.coefficients().b_pr - b_pr).abs() <= 1e-6 * b_pr);
    }
}

/// The condition and the branches survive encoding and decoding.
#[test]
fn condition_and_branches_round_trip() {
    let mut m: Model<P> = example_model_with_branches(
        8,
        3,
        12,
        priors(
            Direction::Increasing,
            Direction::None,
            Direction::Decreasing,
        ),
    )
    .unwrap();
    m.condition = Condition::new("gas charge", "psi", 150.0, 50.0, m.condition.priors).unwrap();
    assert!(m.alpha_branches.b_pr.is_none());
    let blob = blob_of(&m);
    assert_eq!(
        nemm_core::read_header(&blob).unwrap().version,
        nemm_core::FORMAT_VERSION
    );
    let back: Model<P> = decode(&blob).unwrap();
    assert_eq!(back, m);
    assert_eq!(back.condition.name.as_str(), "gas charge");
    assert_eq!(back.condition.value_at(0.5), 100.0);
}

fn branched() -> Model<P> {
    example_model_with_branches(
        8,
        3,
        8,
        priors(
            Direction::Decreasing,
            Direction::Decreasing,
            Direction::Decreasing,
        ),
    )
    .unwrap()
}

fn refused(m: &Model<P>) -> ModelError {
    let e = m.validate().unwrap_err();
    // The encoder refuses it too, and a blob crafted around it does not decode.
    assert!(encode(m, &mut vec![0u8; 64 * 1024]).is_err());
    e
}

/// A corrupt or inconsistent branch is refused with a typed error, never run.
#[test]
fn corrupt_branches_are_refused() {
    let branch_err = |scaler, error| ModelError::Branch { scaler, error };
    let mut m = branched();
    m.alpha_branches.b_fl.as_mut().unwrap().params[3] = f32::NAN;
    assert_eq!(refused(&m), branch_err("b_fl", BranchError::NonFinite));

    let mut m = branched();
    m.alpha_branches.k_pr.as_mut().unwrap().params.pop();
    assert!(matches!(
        refused(&m),
        ModelError::Branch {
            scaler: "k_pr",
            error: BranchError::ParamCountMismatch { .. }
        }
    ));

    let mut m = branched();
    m.alpha_branches.b_pr.as_mut().unwrap().direction = Direction::Increasing;
    assert_eq!(
        refused(&m),
        branch_err("b_pr", BranchError::DirectionMismatch)
    );

    let mut m = branched();
    m.alpha_branches.b_pr.as_mut().unwrap().direction = Direction::None;
    assert_eq!(refused(&m), branch_err("b_pr", BranchError::NoDirection));

    let mut m = branched();
    m.alpha_branches.b_pr = m.alpha_branches.b_fl.clone();
    assert_eq!(
        refused(&m),
        branch_err("b_pr", BranchError::WrongStateInputs { expected: 0 })
    );

    let mut m = branched();
    if let Body::Nemm { k_pr, .. } = &mut m.body {
        k_pr.mlp.params[1] = 0.25; // first row, alpha column
    }
    assert_eq!(
        refused(&m),
        branch_err("k_pr", BranchError::AlphaColumnNotZero)
    );

    let mut m: Model<P> =
        nemm_core::testing::example_model(nemm_core::ModelKind::NemmLight, 8, 3).unwrap();
    m.alpha_branches.k_pr = Some(example_branch(Direction::Decreasing, 1, 4, 1).unwrap());
    assert_eq!(refused(&m), branch_err("k_pr", BranchError::NoScaler));

    let mut m = branched();
    m.alpha_branches.b_fl.as_mut().unwrap().units = 40;
    assert_eq!(
        refused(&m),
        branch_err("b_fl", BranchError::DimensionOutOfRange)
    );

    let mut m = branched();
    m.condition.at_alpha_1 = m.condition.at_alpha_0;
    assert!(matches!(refused(&m), ModelError::Condition { .. }));

    assert!(matches!(
        AlphaBranch::new(Direction::Decreasing, 1, 2, &[0.0; 7]),
        Err(BranchError::ParamCountMismatch {
            expected: 8,
            found: 7
        })
    ));
    assert!(Condition::new(&"x".repeat(33), "-", 0.0, 1.0, Priors::PAPER).is_err());
}

/// A blob whose branch was altered after encoding (CRC fixed up) is refused by the decoder
/// with the model error.
#[test]
fn decoder_refuses_a_blob_with_a_corrupt_branch() {
    let m = branched();
    let blob = blob_of(&m);
    // The last theta_v of k_pr's branch (the last branch parameter of the extension, found
    // by its bytes): make it NaN.
    let n = blob.len() - 4;
    let mut bad = blob.clone();
    let last = m
        .alpha_branches
        .k_pr
        .as_ref()
        .unwrap()
        .params
        .last()
        .unwrap()
        .to_le_bytes();
    let at = blob[..n]
        .windows(4)
        .rposition(|w| w == last)
        .expect("the last branch parameter is in the blob");
    bad[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let crc = nemm_core::CRC.checksum(&bad[..n]);
    bad[n..].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        decode::<P>(&bad).unwrap_err(),
        DecodeError::Invalid(ModelError::Branch {
            scaler: "k_pr",
            error: BranchError::NonFinite
        })
    );
}
