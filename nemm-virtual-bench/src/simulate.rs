//! Time integration of the damper: backward Euler with Newton on the two working-chamber oil
//! contents; valve lifts are advanced with the same implicit step and eliminated exactly.
//!
//! Stability: see docs/virtual-bench.md, section "Integrator". In short, the linearised step
//! matrix is `I + h N D` with `N = A G Aᵀ` (graph Laplacian of the flow network with the
//! non-negative conductances `G`) and `D = diag(dp/dm) >= 0`; it is similar to
//! `I + h D^(1/2) N D^(1/2)`, symmetric positive definite with eigenvalues >= 1, so every
//! Newton system is solvable and the amplification `(I + h N D)^(-1)` has real eigenvalues in
//! (0, 1] for every step size: no step-size limit from the stiff pressure dynamics.

use super::hydraulics::{Damper, Filling, Lifts};
use super::program::Excitation;

/// Counters of the integrator's work.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SolverStats {
    /// Accepted implicit steps (including split ones).
    pub steps: u64,
    /// Newton iterations in total.
    pub newton_iterations: u64,
    /// Steps that were split because Newton did not converge.
    pub splits: u64,
}

/// Noise-free signals of one simulated run at the output sample times.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trace {
    /// Time \[s\].
    pub time_s: Vec<f64>,
    /// Displacement \[m\], positive = extension.
    pub displacement_m: Vec<f64>,
    /// Velocity \[m/s\].
    pub velocity_m_s: Vec<f64>,
    /// Rod force \[N\], positive = tension (tared if configured).
    pub force_n: Vec<f64>,
    /// Rebound-chamber pressure \[Pa\].
    pub p_rebound_pa: Vec<f64>,
    /// Compression-chamber pressure \[Pa\].
    pub p_compression_pa: Vec<f64>,
    /// Reservoir pressure \[Pa\].
    pub p_reservoir_pa: Vec<f64>,
    /// Vapour volume in the compression chamber \[m³\].
    pub vapour_compression_m3: Vec<f64>,
    /// Vapour volume in the rebound chamber \[m³\].
    pub vapour_rebound_m3: Vec<f64>,
    /// Free gas in the compression chamber (normal volume) \[m³\].
    pub gas_compression_m3: Vec<f64>,
    /// Oil loss alpha in effect at each sample \[-\].
    pub alpha: Vec<f64>,
    /// Free gas in the rebound chamber (normal volume) \[m³\].
    pub gas_rebound_m3: Vec<f64>,
    /// Work of the integrator.
    pub stats: SolverStats,
}

/// Integrator settings derived from the configuration.
#[derive(Debug, Clone, Copy)]
pub(crate) struct StepSettings {
    pub(crate) h: f64,
    pub(crate) pressure_tolerance: f64,
    pub(crate) max_iterations: u32,
}

const MAX_SPLIT_DEPTH: u32 = 10;

/// Foam transport: free gas (normal volume) travels with the oil it is dispersed in, enters
/// with the intake flow at `c_intake` gas per oil and separates above the background `c_bg`
/// with time constant `tau`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Foam {
    pub(crate) c_bg: f64,
    pub(crate) c_intake: f64,
    pub(crate) tau: f64,
}

impl Foam {
    /// Cycle-averaged equilibrium of the transport for a sine of peak velocity `v_pk`: the
    /// state a conditioning run leaves (the starting point, so runs settle fast). Mean flows
    /// per direction: intake = base outflow `r_c = A_rod v_pk / pi`, piston flow in either
    /// direction `r_r = A_annulus v_pk / pi`. With the excess concentrations `C = c - c_bg`
    /// and the separation rates `a = V_c / tau`, `b = V_r / tau` the balances
    /// `C_in r_c + C_r r_r = C_c (r_c + r_r + a)` and `C_c r_r = C_r (r_r + b)` give
    /// `C_c = C_in r_c / (r_c + a + r_r b / (r_r + b))`.
    pub(crate) fn conditioned(&self, d: &Damper, v_pk: f64) -> (f64, f64) {
        let r_c = d.a_rod * v_pk / std::f64::consts::PI;
        let r_r = d.a_annulus * v_pk / std::f64::consts::PI;
        let (v_c, v_r) = (d.v_compression0, d.v_rebound0);
        let (a, b) = (v_c / self.tau, v_r / self.tau);
        let c_c = self.c_bg + (self.c_intake - self.c_bg) * r_c / (r_c + a + r_r * b / (r_r + b));
        let c_r = self.c_bg + (c_c - self.c_bg) * r_r / (r_r + b);
        (c_r * v_r, c_c * v_c)
    }
}

struct State<'a> {
    d: &'a Damper,
    f: &'a Filling,
    foam: Foam,
    g_r: f64,
    g_c: f64,
    m_r: f64,
    m_c: f64,
    lifts: Lifts,
    p_r: f64,
    p_c: f64,
    p_res: f64,
    vap_r: f64,
    vap_c: f64,
    ratio: f64,
    dm_r: f64,
    dm_c: f64,
    stats: SolverStats,
    tally: FlowTally,
}

/// Oil volumes that passed each flow path and time integrals of the oil contents, summed over
/// accepted steps (for the conditioning of the free gas, [`condition`]).
#[derive(Debug, Clone, Copy, Default)]
struct FlowTally {
    time: f64,
    /// Intake (reservoir -> compression chamber).
    intake: f64,
    /// Compression chamber -> reservoir.
    base_out: f64,
    /// Piston, rebound -> compression chamber.
    piston_down: f64,
    /// Piston, compression -> rebound chamber.
    piston_up: f64,
    /// `integral m_r dt`, `integral m_c dt`.
    m_r_dt: f64,
    m_c_dt: f64,
}

impl<'a> State<'a> {
    /// The damper at rest in the state `f`.
    fn new(d: &'a Damper, f: &'a Filling, foam: Foam) -> Self {
        State {
            d,
            f,
            foam,
            g_r: f.gas_rebound,
            g_c: f.gas_compression,
            m_r: f.m_rebound0,
            m_c: f.m_compression0,
            lifts: d.rest_lifts(),
            p_r: f.p_rest,
            p_c: f.p_rest,
            p_res: f.p_rest,
            vap_r: 0.0,
            vap_c: 0.0,
            ratio: 0.5,
            dm_r: 0.0,
            dm_c: 0.0,
            stats: SolverStats::default(),
            tally: FlowTally::default(),
        }
    }

    /// One backward-Euler step of length `h` ending at displacement `x1`. Returns false when
    /// Newton did not converge (state untouched).
    fn try_step(&mut self, h: f64, x1: f64, s: &StepSettings) -> bool {
        let d = self.d;
        let (v_r, v_c) = d.volumes(x1);
        // Pressure-equivalent scales for the convergence test: liquid stiffness K / V.
        let scale_r = d.fluid.k_oil / v_r;
        let scale_c = d.fluid.k_oil / v_c;
        // Predictor: previous rate.
        let mut m_r = self.m_r + h * self.dm_r;
        let mut m_c = self.m_c + h * self.dm_c;
        let (mut g_r, mut g_c) = (self.p_r, self.p_c);
        let mut ratio = self.ratio;
        for _ in 0..s.max_iterations {
            let cr = d.fluid.pressure(m_r, self.g_r, v_r, g_r);
            let cc = d.fluid.pressure(m_c, self.g_c, v_c, g_c);
            let (p_res, dres) = d.reservoir_pressure(self.f, m_r, m_c);
            let dp = cr.p - cc.p;
            let pf = d.piston_flow(dp, &self.lifts, h, ratio);
            let bf = d.base_flow(cc.p - p_res, &self.lifts, h);
            let r_r = m_r - self.m_r + h * pf.q;
            let r_c = m_c - self.m_c - h * pf.q + h * bf.q;
            let (gp, gb) = (pf.dq, bf.dq);
            let j11 = 1.0 + h * gp * cr.dp_dm;
            let j12 = -h * gp * cc.dp_dm;
            let j21 = -h * gp * cr.dp_dm - h * gb * dres;
            let j22 = 1.0 + h * gp * cc.dp_dm + h * gb * (cc.dp_dm - dres);
            let det = j11 * j22 - j12 * j21;
            let mut d_r = -(j22 * r_r - j12 * r_c) / det;
            let mut d_c = -(-j21 * r_r + j11 * r_c) / det;
            // Keep the oil contents positive.
            let lim_r = 0.5 * m_r;
            let lim_c = 0.5 * m_c;
            if d_r.abs() > lim_r {
                d_r = d_r.signum() * lim_r;
            }
            if d_c.abs() > lim_c {
                d_c = d_c.signum() * lim_c;
            }
            self.stats.newton_iterations += 1;
            let converged = d_r.abs() * scale_r <= s.pressure_tolerance
                && d_c.abs() * scale_c <= s.pressure_tolerance
                && det.is_finite();
            m_r += d_r;
            m_c += d_c;
            g_r = cr.p;
            g_c = cc.p;
            if dp != 0.0 {
                ratio = pf.dp_valves / dp;
            }
            if converged {
                self.transport(h, pf.q, bf.q, m_r, m_c);
                self.dm_r = (m_r - self.m_r) / h;
                self.dm_c = (m_c - self.m_c) / h;
                self.m_r = m_r;
                self.m_c = m_c;
                self.lifts = Lifts {
                    rebound: pf.lift_rebound,
                    check: pf.lift_check,
                    compression: bf.lift_compression,
                    intake: bf.lift_intake,
                };
                self.p_r = cr.p + d_r * cr.dp_dm;
                self.p_c = cc.p + d_c * cc.dp_dm;
                self.p_res = p_res;
                self.vap_r = cr.vapour;
                self.vap_c = cc.vapour;
                self.ratio = ratio;
                self.stats.steps += 1;
                return true;
            }
            if !(m_r.is_finite() && m_c.is_finite()) {
                return false;
            }
        }
        false
    }

    /// Semi-implicit update of the free gas over the accepted step (`q_p` rebound -> compression
    /// chamber, `q_b` compression chamber -> reservoir): positive and unconditionally stable;
    /// the gas changes slowly (rates <= |q| / m ~ 10 /s), so lagging it by one step is accurate.
    fn transport(&mut self, h: f64, q_p: f64, q_b: f64, m_r: f64, m_c: f64) {
        let fo = self.foam;
        let t = &mut self.tally;
        t.time += h;
        t.intake += h * (-q_b).max(0.0);
        t.base_out += h * q_b.max(0.0);
        t.piston_down += h * q_p.max(0.0);
        t.piston_up += h * (-q_p).max(0.0);
        t.m_r_dt += h * m_r;
        t.m_c_dt += h * m_c;
        let (c_r, c_c) = (self.g_r / self.m_r, self.g_c / self.m_c);
        let (mut in_r, mut out_r, mut in_c, mut out_c) = (0.0, 0.0, 0.0, 0.0);
        if q_p >= 0.0 {
            out_r += q_p / self.m_r;
            in_c += c_r * q_p;
        } else {
            out_c += -q_p / self.m_c;
            in_r += c_c * -q_p;
        }
        if q_b >= 0.0 {
            out_c += q_b / self.m_c;
        } else {
            in_c += fo.c_intake * -q_b;
        }
        in_r += fo.c_bg * m_r / fo.tau;
        in_c += fo.c_bg * m_c / fo.tau;
        self.g_r = (self.g_r + h * in_r) / (1.0 + h * (out_r + 1.0 / fo.tau));
        self.g_c = (self.g_c + h * in_c) / (1.0 + h * (out_c + 1.0 / fo.tau));
    }

    /// A step from `t0` to `t1`, split recursively where Newton fails.
    fn step(&mut self, t0: f64, t1: f64, exc: &Excitation, s: &StepSettings, depth: u32) {
        let h = t1 - t0;
        let x1 = exc.position(t1);
        if self.try_step(h, x1, s) {
            return;
        }
        if depth >= MAX_SPLIT_DEPTH {
            // Accept the best effort of a tiny step rather than abort a whole run; counted.
            self.stats.splits += 1;
            let keep = s.max_iterations;
            let relaxed = StepSettings {
                pressure_tolerance: s.pressure_tolerance * 1e3,
                max_iterations: keep * 4,
                ..*s
            };
            let _ = self.try_step(h, x1, &relaxed);
            return;
        }
        self.stats.splits += 1;
        // Restart the predictor from rest; the rate estimate was what failed.
        self.dm_r = 0.0;
        self.dm_c = 0.0;
        let tm = 0.5 * (t0 + t1);
        self.step(t0, tm, exc, s, depth + 1);
        self.step(tm, t1, exc, s, depth + 1);
    }
}

/// Everything one simulated run needs.
pub(crate) struct Job<'a> {
    pub(crate) damper: &'a Damper,
    /// Initial state (rest pressure, oil and gas contents).
    pub(crate) filling: &'a Filling,
    pub(crate) foam: Foam,
    pub(crate) excitation: &'a Excitation,
    /// Output sample rate \[Hz\].
    pub(crate) sample_rate_hz: f64,
    /// Number of output samples.
    pub(crate) samples: usize,
    pub(crate) settings: StepSettings,
    /// Subtracted from the force \[N\].
    pub(crate) tare: f64,
    /// Oil-loss schedule: from sample `first_sample` on, the damper continues with the
    /// reservoir (oil, gas charge) of `filling` and the foam intake of `foam` (empty: `filling`
    /// and `foam` throughout).
    pub(crate) segments: &'a [Segment],
    /// Oil loss written to [`Trace::alpha`] before the first segment.
    pub(crate) alpha: f64,
}

/// One segment of an oil-loss schedule, in samples.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Segment {
    /// First output sample of the segment.
    pub(crate) first_sample: usize,
    /// Oil loss \[-\].
    pub(crate) alpha: f64,
    /// The rest state of `alpha` (its reservoir replaces the running one).
    pub(crate) filling: Filling,
    /// Foam transport at `alpha`.
    pub(crate) foam: Foam,
}

/// Simulates `job.samples` output samples with internal step `job.settings.h` (rounded to
/// divide the sample period).
pub(crate) fn simulate(job: &Job) -> Trace {
    let (d, f, foam, exc, fs, samples, tare) = (
        job.damper,
        job.filling,
        job.foam,
        job.excitation,
        job.sample_rate_hz,
        job.samples,
        job.tare,
    );
    let settings = &job.settings;
    let sub = ((1.0 / fs) / settings.h).round().max(1.0) as usize;
    let h = 1.0 / fs / sub as f64;
    let mut st = State::new(d, f, foam);
    let mut alpha = job.alpha;
    let mut next_segment = 0;
    let mut tr = Trace::default();
    for v in [
        &mut tr.time_s,
        &mut tr.displacement_m,
        &mut tr.velocity_m_s,
        &mut tr.force_n,
        &mut tr.p_rebound_pa,
        &mut tr.p_compression_pa,
        &mut tr.p_reservoir_pa,
        &mut tr.vapour_compression_m3,
        &mut tr.vapour_rebound_m3,
        &mut tr.gas_compression_m3,
        &mut tr.gas_rebound_m3,
        &mut tr.alpha,
    ] {
        v.reserve(samples);
    }
    for k in 0..samples {
        let t = k as f64 / fs;
        if k > 0 {
            let t_prev = (k - 1) as f64 / fs;
            for j in 0..sub {
                let t0 = t_prev + j as f64 * h;
                let t1 = if j + 1 == sub {
                    t
                } else {
                    t_prev + (j + 1) as f64 * h
                };
                st.step(t0, t1, exc, settings, 0);
            }
        }
        let x = exc.position(t);
        let v = exc.velocity(t);
        let force = d.force(st.p_r, st.p_c, d.friction(v, st.p_r)) - tare;
        tr.time_s.push(t);
        tr.displacement_m.push(x);
        tr.velocity_m_s.push(v);
        tr.force_n.push(force);
        tr.p_rebound_pa.push(st.p_r);
        tr.p_compression_pa.push(st.p_c);
        tr.p_reservoir_pa.push(st.p_res);
        tr.vapour_compression_m3.push(st.vap_c);
        tr.vapour_rebound_m3.push(st.vap_r);
        tr.gas_compression_m3.push(st.g_c);
        tr.gas_rebound_m3.push(st.g_r);
        // A segment takes effect at its first sample: the steps after it run with the new
        // reservoir (oil total, gas charge) and foam intake; the chambers keep their oil, free
        // gas, pressures and valve lifts.
        while let Some(seg) = job.segments.get(next_segment) {
            if seg.first_sample > k {
                break;
            }
            st.f = &seg.filling;
            st.foam = seg.foam;
            alpha = seg.alpha;
            next_segment += 1;
        }
        tr.alpha.push(alpha);
    }
    tr.stats = st.stats;
    tr
}

/// Conditioning of the free gas: the concentrations a long run at the full amplitude of `exc`
/// settles to, so that a recorded run starts in its periodic state (a real bench conditions the
/// damper before it records). Each pass simulates the ramp-in and one full-amplitude period
/// from rest with the current gas, tallies the oil that passed each path during that period
/// and solves the period-averaged transport balances (the `dg/dt` equations of
/// [`State::transport`] integrated over the period, with the concentrations `x = g_c/m_c`,
/// `y = g_r/m_r` held constant):
///
/// ```text
/// c_in Q + y P - x (P + Q) - (x - c_bg) A = 0,   A = integral m_c dt / tau
/// x P - y P - (y - c_bg) B = 0,                  B = integral m_r dt / tau
/// ```
///
/// with the periodic oil balances imposed (intake = base outflow = `Q`, piston flow down = up
/// = `P`, each the mean of the two tallied directions), which is linear in `x`, `y`:
/// `y = (x P + c_bg B) / (P + B)`, `x = (c_in Q + c_bg A + c_bg P B / (P + B)) /
/// (Q + A + P B / (P + B))`. The flows depend only weakly on the gas, so two passes settle it
/// to about a percent. `rest` is the damper at rest (its gas is the first guess); the result
/// is the rest state with the conditioned gas.
pub(crate) fn condition(
    d: &Damper,
    rest: &Filling,
    foam: Foam,
    exc: &Excitation,
    h: f64,
    settings: &StepSettings,
    passes: u32,
) -> Filling {
    let period = exc.conditioning_span_s();
    let ramp_s = exc.ramp_s();
    let n_ramp = (ramp_s / h).ceil() as usize;
    let h_ramp = if n_ramp > 0 {
        ramp_s / n_ramp as f64
    } else {
        0.0
    };
    let n_period = (period / h).ceil().max(8.0) as usize;
    let h_period = period / n_period as f64;
    let mut f = *rest;
    for _ in 0..passes {
        let mut st = State::new(d, &f, foam);
        for k in 0..n_ramp {
            st.step(k as f64 * h_ramp, (k + 1) as f64 * h_ramp, exc, settings, 0);
        }
        st.tally = FlowTally::default();
        for k in 0..n_period {
            let t0 = ramp_s + k as f64 * h_period;
            st.step(t0, t0 + h_period, exc, settings, 0);
        }
        let t = st.tally;
        let (a, b) = (t.m_c_dt / foam.tau, t.m_r_dt / foam.tau);
        let q = 0.5 * (t.intake + t.base_out);
        let p = 0.5 * (t.piston_down + t.piston_up);
        let exchange = p * b / (p + b);
        let x = (foam.c_intake * q + foam.c_bg * (a + exchange)) / (q + a + exchange);
        let y = (x * p + foam.c_bg * b) / (p + b);
        if !(x.is_finite() && y.is_finite() && x >= 0.0 && y >= 0.0) {
            break; // keep the previous estimate (not reached for valid configurations)
        }
        f = d.with_gas(rest, y * f.m_rebound0, x * f.m_compression0);
    }
    f
}
