//! Tests of the virtual test bench: physics (forces, monotonicity, dissipation, oil-loss
//! effects), integrator stability, determinism of the generated files, config errors, plots.

use nemm_dataset::{self as dataset, Run, RunEntry};
use nemm_train::data::preprocess::{process_run, run_signals, SignalConfig};
use nemm_train::report::{cycle_loop, CycleLoop};
use nemm_virtual_bench::config::{self, BenchConfig};
use nemm_virtual_bench::program::{run_spec, RunSpec};
use nemm_virtual_bench::{Trace, VirtualBench};
use std::path::{Path, PathBuf};

fn bench() -> VirtualBench {
    VirtualBench::new(BenchConfig::default())
}

fn spec(b: &VirtualBench, alpha: f64, amp: f64, v: f64) -> RunSpec {
    run_spec(&b.config().program, alpha, amp, v)
}

/// A noise-free trace as a run, reduced to its cycle-averaged loop.
fn trace_loop(b: &VirtualBench, s: &RunSpec, tr: &Trace) -> CycleLoop {
    let run = Run {
        entry: RunEntry {
            file: s.file.clone(),
            oil_loss: s.oil_loss,
            amplitude_m: Some(s.amplitude_m),
            target_velocity_m_s: Some(s.peak_velocity_m_s),
        },
        time_s: tr.time_s.clone(),
        displacement_m: tr.displacement_m.clone(),
        force_n: tr.force_n.clone(),
        velocity_m_s: None,
        alpha: None,
    };
    let fs = b.config().program.sample_rate_hz;
    let sig = process_run(&run, 0, fs, &SignalConfig::default()).expect("signals");
    cycle_loop(&run, &sig.velocity_m_s).expect("loop of a simulated run")
}

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nemm-vb-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn quasi_static_forces_are_monotone_and_passenger_car_sized() {
    let b = bench();
    for alpha in [0.0, 0.15, 0.30] {
        let mut last = f64::NEG_INFINITY;
        for i in -60..=60 {
            let v = i as f64 * 0.02;
            let f = b.quasi_static_force(v, alpha);
            assert!(
                f > last,
                "alpha {alpha}: force not increasing at v = {v}: {f} <= {last}"
            );
            last = f;
        }
    }
    let f = |v: f64| b.quasi_static_force(v, 0.0);
    assert!(
        (150.0..=600.0).contains(&f(0.1)),
        "rebound at 0.1 m/s: {}",
        f(0.1)
    );
    assert!(
        (-400.0..=-60.0).contains(&f(-0.1)),
        "compression at 0.1 m/s: {}",
        f(-0.1)
    );
    assert!(
        (1500.0..=3000.0).contains(&f(1.0)),
        "rebound at 1 m/s: {}",
        f(1.0)
    );
    assert!(
        (-1600.0..=-500.0).contains(&f(-1.0)),
        "compression at 1 m/s: {}",
        f(-1.0)
    );
    for v in [0.1, 0.3, 0.5, 1.0] {
        assert!(
            f(v) > 1.3 * -f(-v),
            "rebound must be stiffer than compression at {v} m/s"
        );
    }
}

#[test]
fn chamber_fluid_has_a_realistic_effective_bulk_modulus() {
    // Gas-free liquid column (oil in series with the pressure tube): about 1.1 GPa. With the
    // undissolved air of a damper in service the effective modulus is a few hundred MPa at
    // working pressures and much lower near the rest pressure.
    let b = bench();
    let c_bg = b.config().aeration.background_gas_per_oil;
    let liquid = b.effective_bulk_modulus_pa(20e5, 0.0);
    assert!((0.9e9..=1.4e9).contains(&liquid), "liquid column {liquid}");
    let mut last = 0.0;
    for p_bar in [3.0, 4.0, 10.0, 20.0, 30.0, 40.0] {
        let k = b.effective_bulk_modulus_pa(p_bar * 1e5, c_bg);
        assert!(k > last && k < liquid, "{p_bar} bar: {k}");
        if (10.0..=30.0).contains(&p_bar) {
            assert!((150e6..=800e6).contains(&k), "{p_bar} bar: {k}");
        }
        last = k;
    }
    assert!(b.effective_bulk_modulus_pa(4e5, c_bg) < 100e6);
    // Oil loss brings foam: softer still.
    let c_15 = b.config().aeration.intake_gas_per_oil(0.15);
    assert!(
        b.effective_bulk_modulus_pa(20e5, c_15) < 0.5 * b.effective_bulk_modulus_pa(20e5, c_bg)
    );
}

#[test]
fn oil_loss_never_raises_the_quasi_static_force_and_lowers_the_gas_charge() {
    // Steady flow: the valve pressure drops do not depend on the oil volume; what oil loss
    // changes is the gas pressure (larger gas volume, Boyle) and with it the pressure-loaded
    // rod-seal friction. So the quasi-static force must not grow with oil loss.
    let b = bench();
    let mut last_p = f64::INFINITY;
    let mut last_gas = f64::NEG_INFINITY;
    for alpha in [0.0, 0.15, 0.30] {
        let r = b.rest_state(alpha);
        assert!(
            r.pressure_pa < last_p && r.reservoir_gas_m3 > last_gas,
            "alpha {alpha}: {r:?}"
        );
        (last_p, last_gas) = (r.pressure_pa, r.reservoir_gas_m3);
    }
    for v in [-1.0, -0.3, -0.05, 0.05, 0.3, 1.0] {
        let f: Vec<f64> = [0.0, 0.15, 0.30]
            .iter()
            .map(|&a| b.quasi_static_force(v, a).abs())
            .collect();
        assert!(f[1] <= f[0] + 1e-9 && f[2] <= f[1] + 1e-9, "v {v}: {f:?}");
    }
}

#[test]
fn slow_run_follows_the_quasi_static_characteristic() {
    // A slow run with a long stroke: at 10 mm the compliance of the aerated oil costs a
    // noticeable part of the stroke even at 0.8 Hz (lost motion is a displacement), at 50 mm
    // it does not.
    let b = bench();
    let s = spec(&b, 0.0, 0.05, 0.052);
    let l = trace_loop(&b, &s, &b.simulate(&s));
    let (reb, comp) = l.quasi_static_n();
    let (qr, qc) = (
        b.quasi_static_force(0.052, 0.0),
        b.quasi_static_force(-0.052, 0.0),
    );
    assert!(
        (reb / qr - 1.0).abs() < 0.08,
        "rebound {reb} vs quasi-static {qr}"
    );
    assert!(
        (comp / qc - 1.0).abs() < 0.08,
        "compression {comp} vs quasi-static {qc}"
    );
}

#[test]
fn energy_per_cycle_is_positive_and_oil_loss_shows_as_hysteresis() {
    let b = bench();
    let loops: Vec<CycleLoop> = [0.0, 0.15, 0.30]
        .iter()
        .map(|&a| {
            let s = spec(&b, a, 0.01, 1.048);
            trace_loop(&b, &s, &b.simulate(&s))
        })
        .collect();
    for l in &loops {
        assert!(
            l.dissipated_energy_j() > 10.0,
            "alpha {}: {} J",
            l.oil_loss,
            l.dissipated_energy_j()
        );
    }
    // Lost motion: the degraded damper dissipates less work per cycle, its loop in the
    // force-velocity plane is wider.
    let e: Vec<f64> = loops.iter().map(CycleLoop::dissipated_energy_j).collect();
    let a: Vec<f64> = loops.iter().map(CycleLoop::hysteresis_area).collect();
    assert!(e[0] > e[1] && e[1] > e[2], "energy {e:?}");
    assert!(a[2] > 1.5 * a[0] && a[1] > a[0], "hysteresis area {a:?}");
    // Asymmetry: early in the compression stroke (first 15 % of the half period after the
    // upper reversal) the degraded damper pushes back much less: the foam in the compression
    // chamber must be compressed first (lost motion), the force stays tensile for longer.
    let early_compression = |l: &CycleLoop| {
        let n = l.force_n.len();
        let (from, to) = (n / 4, n / 4 + (0.15 * n as f64 / 2.0) as usize);
        l.force_n[from..to].iter().sum::<f64>() / (to - from) as f64
    };
    let (c0, c30) = (early_compression(&loops[0]), early_compression(&loops[2]));
    let f_peak = loops[0].peak_force_n();
    assert!(
        c30 - c0 > 0.1 * f_peak,
        "early compression force: {c0} vs {c30} (peak {f_peak})"
    );
    // Other runs dissipate, too (slow and large amplitude).
    for (amp, v) in [(0.05, 0.131), (0.03, 0.524)] {
        let s = spec(&b, 0.30, amp, v);
        let l = trace_loop(&b, &s, &b.simulate(&s));
        assert!(
            l.dissipated_energy_j() > 0.0,
            "{:?}: {}",
            s.file,
            l.dissipated_energy_j()
        );
    }
}

#[test]
fn oil_loss_opens_small_stroke_loops_more_than_large_stroke_loops() {
    let b = bench();
    let norm_area = |alpha: f64, amp: f64| {
        let s = spec(&b, alpha, amp, 0.524);
        let l = trace_loop(&b, &s, &b.simulate(&s));
        l.hysteresis_area()
    };
    let growth_small = norm_area(0.30, 0.01) - norm_area(0.0, 0.01);
    let growth_large = norm_area(0.30, 0.05) - norm_area(0.0, 0.05);
    assert!(
        growth_small > 0.0 && growth_small > growth_large,
        "{growth_small} vs {growth_large}"
    );
}

#[test]
fn loops_at_10_mm_open_with_frequency_and_oil_loss() {
    // Section 3.2: narrow loops at low frequency that open with frequency, more so with oil
    // loss. Runs at 10 mm and 2.1, 4.2, 8.3, 16.7 Hz (0.131 ... 1.048 m/s).
    let b = bench();
    let velocities = [0.131, 0.262, 0.524, 1.048];
    let loops: Vec<Vec<CycleLoop>> = [0.0, 0.15, 0.30]
        .iter()
        .map(|&a| {
            velocities
                .iter()
                .map(|&v| {
                    let s = spec(&b, a, 0.01, v);
                    trace_loop(&b, &s, &b.simulate(&s))
                })
                .collect()
        })
        .collect();
    for row in &loops {
        let area: Vec<f64> = row.iter().map(CycleLoop::hysteresis_area).collect();
        let open: Vec<f64> = row.iter().map(CycleLoop::reversal_opening_n).collect();
        for k in 1..row.len() {
            assert!(
                area[k] > area[k - 1] && open[k] > open[k - 1],
                "alpha {}: loop area {area:?} / opening at v = 0 {open:?} must grow with frequency",
                row[0].oil_loss
            );
        }
    }
    // Without oil loss: narrow at 2.1 Hz, visibly open at 16.7 Hz (relative to the peak force
    // of the 16.7 Hz run, i.e. as in the normalised figure).
    let f_peak = loops[0][3].peak_force_n();
    let (open_slow, open_fast) = (
        loops[0][0].reversal_opening_n(),
        loops[0][3].reversal_opening_n(),
    );
    assert!(
        open_slow < 0.1 * f_peak && open_fast > 0.25 * f_peak,
        "0 %: opening {open_slow} N at 2.1 Hz, {open_fast} N at 16.7 Hz (peak {f_peak} N)"
    );
    // Oil loss widens the loops from 4.2 Hz on, most at the highest frequency.
    for k in 1..velocities.len() {
        let area: Vec<f64> = loops.iter().map(|row| row[k].hysteresis_area()).collect();
        assert!(
            area[1] > area[0] && area[2] > area[1],
            "{} m/s: loop area {area:?} must grow with oil loss",
            velocities[k]
        );
    }
    let growth = |k: usize| loops[2][k].hysteresis_area() / loops[0][k].hysteresis_area();
    assert!(growth(3) > growth(1), "{} vs {}", growth(3), growth(1));
}

#[test]
fn runs_start_with_settled_free_gas() {
    // The free gas is conditioned before a run (a periodic state), so it hardly drifts while
    // the run is recorded, even for the most foaming run.
    let b = bench();
    let s = spec(&b, 0.30, 0.01, 1.048);
    let tr = b.simulate(&s);
    let start = (s.ramp_s * b.config().program.sample_rate_hz) as usize;
    let (g0, g1) = (
        tr.gas_compression_m3[start],
        *tr.gas_compression_m3.last().unwrap(),
    );
    assert!(
        g0 > 0.0 && (g1 / g0 - 1.0).abs() < 0.15,
        "free gas {g0} -> {g1}"
    );
    let (r0, r1) = (tr.gas_rebound_m3[start], *tr.gas_rebound_m3.last().unwrap());
    assert!(
        r0 > 0.0 && (r1 / r0 - 1.0).abs() < 0.15,
        "free gas {r0} -> {r1}"
    );
}

#[test]
fn halving_the_internal_step_changes_the_force_only_slightly() {
    let b = bench();
    for alpha in [0.0, 0.30] {
        let s = spec(&b, alpha, 0.01, 1.048);
        let coarse = b.simulate_with_step(&s, 1e-4); // one implicit step per sample
        let default = b.simulate_with_step(&s, 2.5e-5);
        let half = b.simulate_with_step(&s, 1.25e-5);
        let fmax = default.force_n.iter().fold(0.0f64, |m, f| m.max(f.abs()));
        let diff = |a: &Trace, b: &Trace| {
            a.force_n
                .iter()
                .zip(&b.force_n)
                .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        };
        let rms = |a: &Trace, b: &Trace| {
            let s: f64 = a
                .force_n
                .iter()
                .zip(&b.force_n)
                .map(|(x, y)| (x - y).powi(2))
                .sum();
            (s / a.force_n.len() as f64).sqrt()
        };
        assert!(coarse.force_n.iter().all(|f| f.is_finite()));
        assert!(
            diff(&default, &half) < 0.02 * fmax,
            "alpha {alpha}: max change {}",
            diff(&default, &half)
        );
        assert!(
            rms(&default, &half) < 0.004 * fmax,
            "alpha {alpha}: rms change {}",
            rms(&default, &half)
        );
        // First order: the error roughly halves with the step (coarse vs default is 4x).
        assert!(
            rms(&default, &half) < 0.6 * rms(&coarse, &default),
            "no convergence"
        );
        assert_eq!(
            default.stats.splits, 0,
            "Newton needed step splitting: {:?}",
            default.stats
        );
        assert!(
            default.stats.newton_iterations < 4 * default.stats.steps,
            "{:?}",
            default.stats
        );
    }
}

fn tiny_config(seed_note: &str) -> BenchConfig {
    let mut cfg = BenchConfig {
        name: format!("tiny {seed_note}"),
        ..Default::default()
    };
    cfg.program.oil_loss = vec![0.0, 0.30];
    cfg.program.amplitudes_m = vec![0.01];
    cfg.program.peak_velocities_m_s = vec![0.524];
    cfg.program.min_steady_s = 0.5;
    cfg
}

fn read_tree(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((
                    p.strip_prefix(dir).unwrap().display().to_string(),
                    std::fs::read(&p).unwrap(),
                ));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn generation_is_deterministic_per_seed_and_the_seed_changes_the_noise() {
    let cfg = tiny_config("det");
    let (a, b, c) = (temp_dir("seed-a"), temp_dir("seed-b"), temp_dir("seed-c"));
    let bench = VirtualBench::new(cfg.clone());
    dataset::write(&a, &bench.generate(5, |_, _| {})).unwrap();
    dataset::write(&b, &VirtualBench::new(cfg.clone()).generate(5, |_, _| {})).unwrap();
    dataset::write(&c, &bench.generate(6, |_, _| {})).unwrap();
    let (ta, tb, tc) = (read_tree(&a), read_tree(&b), read_tree(&c));
    assert_eq!(
        ta.len(),
        3,
        "manifest + 2 runs: {:?}",
        ta.iter().map(|t| &t.0).collect::<Vec<_>>()
    );
    assert!(ta == tb, "same seed must give identical bytes");
    let runs_differ = ta
        .iter()
        .zip(&tc)
        .filter(|(x, y)| x.0.ends_with(".csv") && x.1 != y.1)
        .count();
    assert_eq!(
        runs_differ, 2,
        "another seed must change the noise of every run"
    );
    // Same physics under the noise: the seeds differ by noise only.
    let (da, dc) = (dataset::load(&a).unwrap(), dataset::load(&c).unwrap());
    for (ra, rc) in da.runs.iter().zip(&dc.runs) {
        let n = ra.force_n.len() as f64;
        let rms = (ra
            .force_n
            .iter()
            .zip(&rc.force_n)
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        let sigma = cfg.sensors.force_noise_std_n;
        assert!(
            rms > 0.5 * sigma && rms < 3.0 * sigma,
            "{:?}: rms {rms}",
            ra.entry.file
        );
        assert!(ra.velocity_m_s.is_none(), "no velocity column by default");
    }
    // The documented file layout.
    assert_eq!(
        da.runs[1].entry.file,
        PathBuf::from("runs/oil30_a010_v0524.csv")
    );
    let head = String::from_utf8(
        ta.iter()
            .find(|t| t.0.ends_with("oil00_a010_v0524.csv"))
            .unwrap()
            .1[..60]
            .to_vec(),
    )
    .unwrap();
    assert!(
        head.starts_with("time_s,displacement_m,force_n\n0,0,"),
        "{head}"
    );
    for d in [a, b, c] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn velocity_column_is_a_config_option() {
    let mut cfg = tiny_config("vel");
    cfg.program.oil_loss = vec![0.15];
    cfg.sensors.write_velocity = true;
    let ds = VirtualBench::new(cfg).generate(1, |_, _| {});
    let run = &ds.runs[0];
    let v = run.velocity_m_s.as_ref().expect("velocity column");
    let vmax = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    assert!((vmax / 0.524 - 1.0).abs() < 0.05, "{vmax}");
}

#[test]
fn bad_config_files_name_the_file_and_key() {
    let dir = temp_dir("cfg");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bench.toml");
    let text =
        config::DEFAULT_TOML.replace("charge_pressure_pa = 4.0e5", "charge_pressure_pa = -4.0e5");
    std::fs::write(&path, text).unwrap();
    let err = format!("{:#}", config::load(&path).unwrap_err());
    assert!(err.contains("bench.toml:"), "{err}");
    assert!(err.contains("gas.charge_pressure_pa"), "{err}");
    let text = config::DEFAULT_TOML.replace("[sensors]", "[sensor]");
    std::fs::write(&path, text).unwrap();
    let err = format!("{:#}", config::load(&path).unwrap_err());
    assert!(err.contains("sensor") && err.contains("line"), "{err}");
    let err = format!("{:#}", config::load(&dir.join("missing.toml")).unwrap_err());
    assert!(err.contains("missing.toml"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn plots_are_written_for_a_generated_dataset() {
    let cfg = tiny_config("plot");
    let (data, out) = (temp_dir("plot-data"), temp_dir("plot-out"));
    dataset::write(&data, &VirtualBench::new(cfg).generate(3, |_, _| {})).unwrap();
    let plotted = nemm_train::report::plot_dataset(&data, &out).unwrap();
    assert!(plotted.skipped.is_empty(), "{:?}", plotted.skipped);
    let files = plotted.written;
    let names: Vec<String> = files
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        [
            "force_velocity_loops.png",
            "difference_loops.png",
            "quasi_static.png"
        ]
    );
    for f in &files {
        let bytes = std::fs::read(f).unwrap();
        assert!(
            bytes.len() > 10_000 && &bytes[1..4] == b"PNG",
            "{}",
            f.display()
        );
    }
    // Measured (noisy, quantised) runs give sensible loops.
    let loaded = dataset::load(&data).unwrap();
    let signals = run_signals(&loaded, &SignalConfig::default()).unwrap();
    for (run, sig) in loaded.runs.iter().zip(&signals) {
        let l = cycle_loop(run, &sig.velocity_m_s).unwrap();
        assert!(l.dissipated_energy_j() > 0.0);
        let vmax = l.velocity_m_s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!((vmax / 0.524 - 1.0).abs() < 0.05, "{vmax}");
    }
    let _ = std::fs::remove_dir_all(&data);
    let _ = std::fs::remove_dir_all(&out);
}

/// An oil-loss schedule: the `alpha` column follows the segments, and the force is that of the
/// constant-level run until the first change and differs from it afterwards.
#[test]
fn alpha_schedule_changes_the_force_from_its_first_switch_on() {
    let cfg = nemm_virtual_bench::fixtures::fixtures()
        .into_iter()
        .find(|f| f.name == "alpha_schedule_1khz")
        .unwrap()
        .config;
    let mut constant = cfg.clone();
    constant.program.alpha_schedule = None;
    let (with, without) = (VirtualBench::new(cfg), VirtualBench::new(constant));
    let spec = with.runs().remove(0);
    let plain = without.runs().remove(0);
    assert!(plain.alpha_segments.is_empty());
    let (a, b) = (with.measure(&spec, 5), without.measure(&plain, 5));
    let alpha = a.alpha.as_ref().expect("alpha column");
    assert!(b.alpha.is_none());
    let fs = with.config().program.sample_rate_hz;
    for (i, &x) in alpha.iter().enumerate() {
        assert_eq!(x, spec.alpha_at(i as f64 / fs), "sample {i}");
    }
    let switch = alpha.iter().position(|&x| x != alpha[0]).unwrap();
    assert_eq!(a.force_n[..switch], b.force_n[..switch]);
    let rms = |r: std::ops::Range<usize>| {
        (r.clone()
            .map(|i| (a.force_n[i] - b.force_n[i]).powi(2))
            .sum::<f64>()
            / r.len() as f64)
            .sqrt()
    };
    let after = rms(switch..a.len());
    assert!(
        after > 10.0,
        "force RMS difference after the switch {after} N"
    );
}

#[test]
fn the_free_gas_and_so_the_pressure_element_depend_on_the_run_not_on_the_level_alone() {
    // Two conditions of the programme at 10 mm, slow and fast, at 0 / 15 / 30 %: the fast run
    // draws in more foam at each lossy level, and the compression chamber softens with the
    // level on both. On the default bench the fast 15 % run holds more free gas than the
    // slow 30 % one: the gas is a state of the run, not a function of alpha.
    use nemm_virtual_bench::reference::{every_condition, every_condition_markdown, Coefficient};
    let mut cfg = BenchConfig::default();
    cfg.program.amplitudes_m = vec![0.01];
    cfg.program.peak_velocities_m_s = vec![0.131, 1.048];
    let refs = every_condition(&VirtualBench::new(cfg)).expect("reference per condition");
    assert_eq!(refs.len(), 2);
    let (slow, fast) = (&refs[0], &refs[1]);
    assert_eq!(slow.run.peak_velocity_m_s, 0.131);
    let gas = |r: &nemm_virtual_bench::reference::EmmReference, a: f64| {
        r.levels
            .iter()
            .find(|l| l.alpha == a)
            .expect("level")
            .compression
            .gas_per_oil
    };
    for a in [0.15, 0.3] {
        assert!(gas(fast, a) > gas(slow, a), "alpha {a}");
        for r in refs.iter() {
            let k = r.relative(Coefficient::KPrCompression, a).expect("k_c");
            assert!(k < -0.5, "{:?} at {a}: {k}", r.run);
        }
    }
    assert!(gas(fast, 0.15) > gas(slow, 0.3));
    let md = every_condition_markdown(&refs);
    assert!(md.contains("| 10 | 1.048 | 16.7 | 0.3 |"), "{md}");
    assert!(md.contains("- alpha 0.3: from "), "{md}");
}
