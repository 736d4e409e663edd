//! Constitutive laws of the twin-tube damper: flow through restrictions and valves, pressure of
//! an oil/gas/vapour filled chamber, reservoir gas, rest state for a given oil loss.
//!
//! Units: SI throughout, pressures absolute \[Pa\], flows \[m³/s\] of oil measured at the
//! reference (atmospheric) pressure, i.e. mass flow / reference density, so that the chamber
//! oil contents are exactly conserved.

use super::config::{BenchConfig, DiscValve, Restriction};

/// A regularised power-law restriction: `q = c dp (dp² + t²)^s`, `s = (1/r - 1)/2`,
/// which is `dp = B |q|^r` for `|dp| >> t` and linear (laminar) for `|dp| << t`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PowerLaw {
    c: f64,
    s: f64,
    t2: f64,
}

impl PowerLaw {
    pub(crate) fn new(r: &Restriction, laminar_pa: f64) -> Self {
        // dp_ref = B q_ref^r  =>  q = (dp / B)^(1/r) = q_ref (dp / dp_ref)^(1/r)
        let inv = 1.0 / r.exponent;
        let c = r.flow_ref_m3_s / r.dp_ref_pa.powf(inv);
        PowerLaw {
            c,
            s: 0.5 * (inv - 1.0),
            t2: laminar_pa * laminar_pa,
        }
    }

    /// Flow and its derivative with respect to the pressure difference.
    #[inline]
    pub(crate) fn flow(&self, dp: f64) -> (f64, f64) {
        let a = dp * dp + self.t2;
        let g = a.powf(self.s);
        let q = self.c * dp * g;
        // d/ddp [dp a^s] = a^s + 2 s dp² a^(s-1) = a^(s-1) (a + 2 s dp²)
        let dq = self.c * g * (a + 2.0 * self.s * dp * dp) / a;
        (q, dq)
    }
}

/// Sharp-edged orifice `q = Cd A sqrt(2 |dp| / rho) sign(dp)`, regularised below `t`:
/// `q = k A dp (dp² + t²)^(-1/4)` with `k = Cd sqrt(2/rho)`.
#[inline]
fn orifice(k_area: f64, dp: f64, t2: f64) -> (f64, f64, f64) {
    let a = dp * dp + t2;
    let a_q = a.sqrt().sqrt(); // a^(1/4)
    let unit = dp / a_q; // q per (k A)
    let q = k_area * unit;
    // d/ddp [dp a^(-1/4)] = a^(-1/4) - 0.5 dp² a^(-5/4) = a^(-5/4) (a - 0.5 dp²)
    let dq = k_area * (a - 0.5 * dp * dp) / (a * a_q);
    (q, dq, unit)
}

/// Smooth ramp `0.5 (z + sqrt(z² + e²))` and its derivative.
#[inline]
fn ramp(z: f64, e: f64) -> (f64, f64) {
    let r = (z * z + e * e).sqrt();
    (0.5 * (z + r), 0.5 * (1.0 + z / r))
}

/// A preloaded disc valve: static lift `y_ss(dp) = sat((dp - preload) / span)` in `[0, 1]`
/// (Appendix A, eq. A.4: spring force balances pressure force above the preload), flow through
/// the lift-proportional orifice area, first-order lag `T dy/dt = y_ss - y`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Disc {
    preload: f64,
    inv_span: f64,
    e: f64,
    /// `Cd A_max sqrt(2 / rho)`.
    k_area: f64,
    pub(crate) tau: f64,
}

impl Disc {
    pub(crate) fn new(d: &DiscValve, rho: f64, smoothing_pa: f64) -> Self {
        Disc {
            preload: d.preload_dp_pa,
            inv_span: 1.0 / d.full_lift_dp_pa,
            e: smoothing_pa / d.full_lift_dp_pa,
            k_area: d.discharge_coefficient * d.max_area_m2 * (2.0 / rho).sqrt(),
            tau: d.time_constant_s,
        }
    }

    /// Static lift for an opening pressure difference and its derivative \[1/Pa\].
    #[inline]
    pub(crate) fn static_lift(&self, dp_open: f64) -> (f64, f64) {
        let z = (dp_open - self.preload) * self.inv_span;
        let (r0, d0) = ramp(z, self.e);
        let (r1, d1) = ramp(z - 1.0, self.e);
        (r0 - r1, (d0 - d1) * self.inv_span)
    }
}

/// Pressure of a working chamber of volume `v` holding oil (`m`, volume at reference pressure)
/// and free gas (`g`, normal volume). Fluid volume `f(p) = m exp(-(p - p_ref)/K) +
/// g (p_ref/p)^(1/n)` is decreasing and convex in `p`; the chamber pressure solves `f(p) = v`,
/// or equals the cavitation pressure when even there `f < v` (a vapour cavity fills the rest).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Fluid {
    /// Bulk modulus of the gas-free liquid column (oil and pressure tube, [`liquid_bulk_modulus`]).
    pub(crate) k_oil: f64,
    pub(crate) p_ref: f64,
    pub(crate) p_cav: f64,
    pub(crate) inv_n_bubble: f64,
}

/// Result of a chamber-pressure evaluation.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ChamberPressure {
    pub(crate) p: f64,
    /// dp/dm (0 while cavitating).
    pub(crate) dp_dm: f64,
    /// Vapour volume \[m³\] (0 unless cavitating).
    pub(crate) vapour: f64,
}

impl Fluid {
    /// Tangent bulk modulus `-V dp/dV` of a mixture of oil with `gas_per_oil` normal volumes of
    /// free gas per volume of oil at pressure `p` (Wood: `1/K = (1-e)/K_l + e/(n p)` with the
    /// in-situ gas fraction `e`).
    pub(crate) fn tangent_modulus(&self, gas_per_oil: f64, p: f64) -> f64 {
        let e = (-(p - self.p_ref) / self.k_oil).exp();
        let (vg, dvg) = self.gas_volume(gas_per_oil, p);
        (e + vg) / (e / self.k_oil - dvg)
    }

    #[inline]
    fn gas_volume(&self, g: f64, p: f64) -> (f64, f64) {
        if g == 0.0 {
            return (0.0, 0.0);
        }
        let vg = if self.inv_n_bubble == 1.0 {
            g * self.p_ref / p
        } else {
            g * (self.p_ref / p).powf(self.inv_n_bubble)
        };
        // d vg / dp = -(1/n) vg / p
        (vg, -self.inv_n_bubble * vg / p)
    }

    /// Solves the chamber pressure; `guess` is the previous pressure (any positive value works).
    pub(crate) fn pressure(&self, m: f64, g: f64, v: f64, guess: f64) -> ChamberPressure {
        let e_cav = (-(self.p_cav - self.p_ref) / self.k_oil).exp();
        let (vg_cav, _) = self.gas_volume(g, self.p_cav);
        let f_cav = m * e_cav + vg_cav;
        if f_cav <= v {
            return ChamberPressure {
                p: self.p_cav,
                dp_dm: 0.0,
                vapour: v - f_cav,
            };
        }
        if g == 0.0 {
            // closed form: m exp(-(p - p_ref)/K) = v
            let p = self.p_ref + self.k_oil * (m / v).ln();
            return ChamberPressure {
                p,
                dp_dm: self.k_oil / m,
                vapour: 0.0,
            };
        }
        // Newton from the left of the root converges monotonically (f convex, decreasing).
        // Lower bounds: oil alone or gas alone filling v.
        let lb_oil = if m > 0.0 {
            self.p_ref + self.k_oil * (m / v).ln()
        } else {
            self.p_cav
        };
        let lb_gas = self.p_ref * (g / v).powf(1.0 / self.inv_n_bubble);
        let mut p = self.p_cav.max(lb_oil).max(lb_gas);
        if guess > p {
            let e = (-(guess - self.p_ref) / self.k_oil).exp();
            let (vg, _) = self.gas_volume(g, guess);
            if m * e + vg >= v {
                p = guess;
            }
        }
        let mut slope = 0.0;
        for _ in 0..60 {
            let e = (-(p - self.p_ref) / self.k_oil).exp();
            let (vg, dvg) = self.gas_volume(g, p);
            let f = m * e + vg;
            slope = m * e / self.k_oil - dvg; // -f'(p) > 0
            let step = (f - v) / slope;
            p += step;
            if step.abs() <= 1e-9 * p + 1e-6 {
                break;
            }
        }
        let e = (-(p - self.p_ref) / self.k_oil).exp();
        ChamberPressure {
            p,
            dp_dm: e / slope,
            vapour: 0.0,
        }
    }
}

/// Bulk modulus of the gas-free liquid column in the pressure tube: the oil in series with
/// the radial expansion of the thin-walled tube, `1/K_l = 1/K_oil + D/(t E)` (closed-end axial
/// strain neglected). Used in the exponential oil law, which is exact to first order in
/// `(p - p_ref) D/(t E)` (< 1e-3 up to 80 bar).
pub(crate) fn liquid_bulk_modulus(cfg: &BenchConfig) -> f64 {
    let g = &cfg.geometry;
    let tube = g.piston_diameter_m / (g.pressure_tube_wall_m * g.tube_youngs_modulus_pa);
    1.0 / (1.0 / cfg.oil.bulk_modulus_pa + tube)
}

/// Damper constants derived from the configuration.
#[derive(Debug, Clone)]
pub(crate) struct Damper {
    pub(crate) a_piston: f64,
    pub(crate) a_rod: f64,
    pub(crate) a_annulus: f64,
    pub(crate) v_rebound0: f64,
    pub(crate) v_compression0: f64,
    pub(crate) v_reservoir: f64,
    pub(crate) fluid: Fluid,
    pub(crate) p_atm: f64,
    pub(crate) n_gas: f64,
    pub(crate) piston_leak: PowerLaw,
    pub(crate) piston_port: PowerLaw,
    pub(crate) rebound_valve: Disc,
    pub(crate) check_valve: Disc,
    pub(crate) base_leak: PowerLaw,
    pub(crate) compression_valve: Disc,
    pub(crate) intake_valve: Disc,
    pub(crate) orifice_t2: f64,
    pub(crate) friction_coulomb: f64,
    pub(crate) friction_pressure: f64,
    pub(crate) friction_v: f64,
}

/// Oil-loss dependent state of the damper at rest (mid-stroke).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Filling {
    /// Free gas normal volumes in the rebound / compression chamber \[m³\].
    pub(crate) gas_rebound: f64,
    pub(crate) gas_compression: f64,
    /// Total oil (reference volume) in the damper \[m³\].
    pub(crate) oil_total: f64,
    /// Pressure at rest \[Pa\].
    pub(crate) p_rest: f64,
    /// Reservoir gas volume at rest \[m³\].
    pub(crate) v_gas_rest: f64,
    /// Oil contents at rest \[m³\].
    pub(crate) m_rebound0: f64,
    pub(crate) m_compression0: f64,
}

/// Valve lifts (normalised, 0..1).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Lifts {
    pub(crate) rebound: f64,
    pub(crate) check: f64,
    pub(crate) compression: f64,
    pub(crate) intake: f64,
}

/// Flow through the piston (rebound -> compression chamber positive).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PistonFlow {
    pub(crate) q: f64,
    pub(crate) dq: f64,
    /// Pressure difference across the valve group (behind the port restriction).
    pub(crate) dp_valves: f64,
    pub(crate) lift_rebound: f64,
    pub(crate) lift_check: f64,
}

/// Flow through the base valve (compression chamber -> reservoir positive).
#[derive(Debug, Clone, Copy)]
pub(crate) struct BaseFlow {
    pub(crate) q: f64,
    pub(crate) dq: f64,
    pub(crate) lift_compression: f64,
    pub(crate) lift_intake: f64,
}

/// Backward-Euler update of a first-order lag: `y1 = (y0 + a y_ss) / (1 + a)`, `a = h / T`.
#[inline]
fn lag(y0: f64, y_ss: f64, dy_ss: f64, h: f64, tau: f64) -> (f64, f64) {
    let a = h / tau;
    ((y0 + a * y_ss) / (1.0 + a), a / (1.0 + a) * dy_ss)
}

impl Damper {
    pub(crate) fn new(cfg: &BenchConfig) -> Self {
        let g = &cfg.geometry;
        let a_piston = std::f64::consts::PI / 4.0 * g.piston_diameter_m.powi(2);
        let a_rod = std::f64::consts::PI / 4.0 * g.rod_diameter_m.powi(2);
        let lam = cfg.solver.laminar_transition_pa;
        let smooth = cfg.solver.valve_smoothing_pa;
        let rho = cfg.oil.density_kg_m3;
        Damper {
            a_piston,
            a_rod,
            a_annulus: a_piston - a_rod,
            v_rebound0: (a_piston - a_rod) * g.rebound_chamber_length_m,
            v_compression0: a_piston * g.compression_chamber_length_m,
            v_reservoir: g.reservoir_volume_m3,
            fluid: Fluid {
                k_oil: liquid_bulk_modulus(cfg),
                p_ref: cfg.gas.atmospheric_pressure_pa,
                p_cav: cfg.oil.cavitation_pressure_pa,
                inv_n_bubble: 1.0 / cfg.gas.bubble_polytropic_exponent,
            },
            p_atm: cfg.gas.atmospheric_pressure_pa,
            n_gas: cfg.gas.polytropic_exponent,
            piston_leak: PowerLaw::new(&cfg.piston.leak, lam),
            piston_port: PowerLaw::new(&cfg.piston.port, lam),
            rebound_valve: Disc::new(&cfg.piston.rebound_valve, rho, smooth),
            check_valve: Disc::new(&cfg.piston.check_valve, rho, smooth),
            base_leak: PowerLaw::new(&cfg.base.leak, lam),
            compression_valve: Disc::new(&cfg.base.compression_valve, rho, smooth),
            intake_valve: Disc::new(&cfg.base.intake_valve, rho, smooth),
            orifice_t2: lam * lam,
            friction_coulomb: cfg.friction.coulomb_n,
            friction_pressure: cfg.friction.pressure_coefficient_n_per_pa,
            friction_v: cfg.friction.smoothing_velocity_m_s,
        }
    }

    /// Chamber volumes at displacement `x` (positive = extension).
    #[inline]
    pub(crate) fn volumes(&self, x: f64) -> (f64, f64) {
        (
            self.v_rebound0 - self.a_annulus * x,
            self.v_compression0 + self.a_piston * x,
        )
    }

    /// The filled damper at rest for oil loss `alpha`: the lost oil leaves the reservoir, the
    /// gas charge (reduced by `retained_fraction`) expands isothermally into the freed volume.
    pub(crate) fn filling(&self, cfg: &BenchConfig, alpha: f64) -> Filling {
        let c_bg = cfg.aeration.background_gas_per_oil;
        let gas_c = c_bg * self.v_compression0;
        let gas_r = c_bg * self.v_rebound0;
        let fl = &self.fluid;
        // Without oil loss: chambers and reservoir at the charge pressure.
        let p0 = cfg.gas.charge_pressure_pa;
        let oil_at = |v: f64, g: f64, p: f64| self.oil_for(v, g, p);
        let (gas_c0, gas_r0) = (gas_c, gas_r);
        let oil_full = oil_at(self.v_rebound0, gas_r0, p0)
            + oil_at(self.v_compression0, gas_c0, p0)
            + cfg.geometry.reservoir_oil_volume_m3;
        let v_gas_full = self.v_reservoir - cfg.geometry.reservoir_oil_volume_m3;
        // Normal volume of the whole gas charge (reservoir + entrained).
        let gas_normal_full = p0 * v_gas_full / fl.p_ref + gas_c0 + gas_r0;
        let gas_normal = cfg.gas.retained_fraction * gas_normal_full;
        let oil_total = (1.0 - alpha) * oil_full;
        let reservoir_normal = (gas_normal - gas_c - gas_r).max(1e-3 * gas_normal);
        // Rest pressure: the reservoir gas (isothermal at rest) must fill what the oil leaves.
        let mismatch = |p: f64| {
            let m_res = oil_total
                - oil_at(self.v_rebound0, gas_r, p)
                - oil_at(self.v_compression0, gas_c, p);
            let v_gas = self.v_reservoir - m_res;
            reservoir_normal * fl.p_ref / v_gas - p
        };
        let (mut lo, mut hi) = (fl.p_cav, 1e8);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if mismatch(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let p_rest = 0.5 * (lo + hi);
        let m_r = oil_at(self.v_rebound0, gas_r, p_rest);
        let m_c = oil_at(self.v_compression0, gas_c, p_rest);
        Filling {
            gas_rebound: gas_r,
            gas_compression: gas_c,
            oil_total,
            p_rest,
            v_gas_rest: self.v_reservoir - (oil_total - m_r - m_c),
            m_rebound0: m_r,
            m_compression0: m_c,
        }
    }

    /// Oil (reference volume) that fills volume `v` at pressure `p` next to free gas `g`.
    pub(crate) fn oil_for(&self, v: f64, g: f64, p: f64) -> f64 {
        let fl = &self.fluid;
        let (vg, _) = fl.gas_volume(g, p);
        (v - vg) * ((p - fl.p_ref) / fl.k_oil).exp()
    }

    /// The rest state with other free-gas contents in the working chambers (the foam left by
    /// a conditioning run): same pressure, the reservoir takes up the displaced oil.
    pub(crate) fn with_gas(&self, f: &Filling, gas_rebound: f64, gas_compression: f64) -> Filling {
        let m_r = self.oil_for(self.v_rebound0, gas_rebound, f.p_rest);
        let m_c = self.oil_for(self.v_compression0, gas_compression, f.p_rest);
        Filling {
            gas_rebound,
            gas_compression,
            v_gas_rest: self.v_reservoir - (f.oil_total - m_r - m_c),
            m_rebound0: m_r,
            m_compression0: m_c,
            ..*f
        }
    }

    /// Reservoir pressure for the oil contents of the working chambers (polytropic, B.1-B.2),
    /// and dp_res / d(m_r + m_c).
    #[inline]
    pub(crate) fn reservoir_pressure(&self, f: &Filling, m_r: f64, m_c: f64) -> (f64, f64) {
        let m_res = f.oil_total - m_r - m_c;
        // Never let the gas pocket vanish numerically (the validated programme stays far away).
        let v_gas = (self.v_reservoir - m_res).max(1e-3 * f.v_gas_rest);
        let p = f.p_rest * (f.v_gas_rest / v_gas).powf(self.n_gas);
        // dV_gas / d(m_r + m_c) = +1, dp/dV_gas = -n p / V_gas
        (p, -self.n_gas * p / v_gas)
    }

    /// Piston flow for the total pressure difference `dp = p_r - p_c`, with the valve lifts
    /// advanced implicitly over `h` from `lifts0`. The port restriction is in series with the
    /// valve group; the group's pressure difference solves `q_group(dp1) = q_port(dp - dp1)`.
    pub(crate) fn piston_flow(
        &self,
        dp: f64,
        lifts0: &Lifts,
        h: f64,
        guess_ratio: f64,
    ) -> PistonFlow {
        let group = |dp1: f64| {
            let (ql, dql) = self.piston_leak.flow(dp1);
            let (ys, dys) = self.rebound_valve.static_lift(dp1);
            let (yr, dyr) = lag(lifts0.rebound, ys, dys, h, self.rebound_valve.tau);
            let (qr, dqr, ur) = orifice(self.rebound_valve.k_area * yr, dp1, self.orifice_t2);
            let (ys, dys) = self.check_valve.static_lift(-dp1);
            let (yc, dyc) = lag(lifts0.check, ys, dys, h, self.check_valve.tau);
            let (qc, dqc, uc) = orifice(self.check_valve.k_area * yc, dp1, self.orifice_t2);
            let q = ql + qr + qc;
            let dq = dql + dqr + self.rebound_valve.k_area * ur * dyr + dqc
                - self.check_valve.k_area * uc * dyc;
            (q, dq.max(1e-18), yr, yc)
        };
        // Solve q_group(dp1) - q_port(dp - dp1) = 0, increasing in dp1, root between 0 and dp.
        let (mut lo, mut hi) = if dp >= 0.0 { (0.0, dp) } else { (dp, 0.0) };
        let mut dp1 = dp * guess_ratio.clamp(0.0, 1.0);
        let mut out = (0.0, 0.0, 0.0, 0.0, 0.0);
        for _ in 0..60 {
            let (qg, dqg, yr, yc) = group(dp1);
            let (qp, dqp) = self.piston_port.flow(dp - dp1);
            let r = qg - qp;
            out = (qg, dqg, dqp, yr, yc);
            if r > 0.0 {
                hi = dp1;
            } else {
                lo = dp1;
            }
            let tol = 1e-12 * qg.abs().max(qp.abs()) + 1e-16;
            if r.abs() <= tol {
                break;
            }
            let mut next = dp1 - r / (dqg + dqp);
            if !(next > lo && next < hi) {
                next = 0.5 * (lo + hi);
            }
            if (next - dp1).abs() <= 1e-9 * dp.abs() + 1e-9 {
                dp1 = next;
                let (qg, dqg, yr, yc) = group(dp1);
                let (_, dqp) = self.piston_port.flow(dp - dp1);
                out = (qg, dqg, dqp, yr, yc);
                break;
            }
            dp1 = next;
        }
        let (q, g_group, g_port, yr, yc) = out;
        PistonFlow {
            q,
            dq: g_group * g_port / (g_group + g_port),
            dp_valves: dp1,
            lift_rebound: yr,
            lift_check: yc,
        }
    }

    /// Base-valve flow for `dp = p_c - p_res`, lifts advanced implicitly over `h`.
    pub(crate) fn base_flow(&self, dp: f64, lifts0: &Lifts, h: f64) -> BaseFlow {
        let (ql, dql) = self.base_leak.flow(dp);
        let (ys, dys) = self.compression_valve.static_lift(dp);
        let (yv, dyv) = lag(lifts0.compression, ys, dys, h, self.compression_valve.tau);
        let (qv, dqv, uv) = orifice(self.compression_valve.k_area * yv, dp, self.orifice_t2);
        let (ys, dys) = self.intake_valve.static_lift(-dp);
        let (yi, dyi) = lag(lifts0.intake, ys, dys, h, self.intake_valve.tau);
        let (qi, dqi, ui) = orifice(self.intake_valve.k_area * yi, dp, self.orifice_t2);
        let dq = dql + dqv + self.compression_valve.k_area * uv * dyv + dqi
            - self.intake_valve.k_area * ui * dyi;
        BaseFlow {
            q: ql + qv + qi,
            dq: dq.max(1e-18),
            lift_compression: yv,
            lift_intake: yi,
        }
    }

    /// Seal friction for rod velocity `v` and rebound-chamber pressure `p_r`.
    #[inline]
    pub(crate) fn friction(&self, v: f64, p_r: f64) -> f64 {
        let level = self.friction_coulomb + self.friction_pressure * (p_r - self.p_atm).max(0.0);
        level * (v / self.friction_v).tanh()
    }

    /// Rod force (tension positive) from the chamber pressures and the friction.
    #[inline]
    pub(crate) fn force(&self, p_r: f64, p_c: f64, friction: f64) -> f64 {
        p_r * self.a_annulus - p_c * self.a_piston + self.p_atm * self.a_rod + friction
    }

    /// Static lifts at rest (all pressure differences zero).
    pub(crate) fn rest_lifts(&self) -> Lifts {
        Lifts {
            rebound: self.rebound_valve.static_lift(0.0).0,
            check: self.check_valve.static_lift(0.0).0,
            compression: self.compression_valve.static_lift(0.0).0,
            intake: self.intake_valve.static_lift(0.0).0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn damper() -> (BenchConfig, Damper) {
        let cfg = BenchConfig::default();
        let d = Damper::new(&cfg);
        (cfg, d)
    }

    #[test]
    fn power_law_matches_reference_point_and_derivative() {
        let (cfg, d) = damper();
        let r = &cfg.piston.leak;
        let (q, _) = d.piston_leak.flow(r.dp_ref_pa);
        assert!((q / r.flow_ref_m3_s - 1.0).abs() < 1e-3, "{q}");
        for dp in [-3e6, -1e4, -10.0, 0.0, 7.0, 2e3, 5e5, 4e6] {
            let (_, dq) = d.piston_leak.flow(dp);
            let e = 1e-3 * (dp.abs() + 1.0);
            let num = (d.piston_leak.flow(dp + e).0 - d.piston_leak.flow(dp - e).0) / (2.0 * e);
            assert!(
                (dq - num).abs() <= 1e-5 * num.abs(),
                "dp {dp}: {dq} vs {num}"
            );
            assert!(dq > 0.0);
        }
    }

    #[test]
    fn chamber_pressure_inverts_fluid_volume() {
        let (_, d) = damper();
        let fl = d.fluid;
        let v = 1e-4;
        for g in [0.0, 1e-7, 3e-6] {
            for p_true in [2e4, 1e5, 4e5, 3e6, 6e6] {
                let (vg, _) = fl.gas_volume(g, p_true);
                let m = (v - vg) * ((p_true - fl.p_ref) / fl.k_oil).exp();
                for guess in [1e3, p_true * 0.5, p_true * 3.0] {
                    let c = fl.pressure(m, g, v, guess);
                    assert!(
                        (c.p - p_true).abs() < 1e-6 * p_true + 1e-3,
                        "{g} {p_true}: {}",
                        c.p
                    );
                    let dm = 1e-9 * m;
                    let num = (fl.pressure(m + dm, g, v, guess).p
                        - fl.pressure(m - dm, g, v, guess).p)
                        / (2.0 * dm);
                    assert!((c.dp_dm / num - 1.0).abs() < 1e-3, "{} vs {}", c.dp_dm, num);
                }
            }
        }
        // Too little fluid: vapour cavity at the cavitation pressure.
        let c = fl.pressure(0.9 * v, 0.0, v, 1e5);
        assert_eq!(c.p, fl.p_cav);
        assert!(c.vapour > 0.09 * v && c.dp_dm == 0.0);
    }

    #[test]
    fn tangent_modulus_matches_the_chamber_pressure_law() {
        let (cfg, d) = damper();
        let fl = d.fluid;
        // Liquid column: oil in series with the tube, D / (t E) = 1.2e-10 / Pa.
        let tube = cfg.geometry.piston_diameter_m
            / (cfg.geometry.pressure_tube_wall_m * cfg.geometry.tube_youngs_modulus_pa);
        assert!((1.0 / fl.k_oil - 1.0 / cfg.oil.bulk_modulus_pa - tube).abs() < 1e-15);
        // -V dp/dV of a chamber holding unit oil and gas g, from the pressure solver.
        for g in [0.0, 0.04, 0.2] {
            for p in [3e5, 1e6, 4e6] {
                let k = fl.tangent_modulus(g, p);
                let (vg, _) = fl.gas_volume(g, p);
                let v = (-(p - fl.p_ref) / fl.k_oil).exp() + vg;
                let dv = 1e-7 * v;
                let p1 = fl.pressure(1.0, g, v - dv, p).p;
                let p0 = fl.pressure(1.0, g, v + dv, p).p;
                let num = v * (p1 - p0) / (2.0 * dv);
                assert!((k / num - 1.0).abs() < 1e-4, "g {g} p {p}: {k} vs {num}");
            }
        }
    }

    #[test]
    fn oil_loss_lowers_the_rest_pressure() {
        let (cfg, d) = damper();
        let f0 = d.filling(&cfg, 0.0);
        assert!(
            (f0.p_rest / cfg.gas.charge_pressure_pa - 1.0).abs() < 1e-6,
            "{}",
            f0.p_rest
        );
        let f15 = d.filling(&cfg, 0.15);
        let f30 = d.filling(&cfg, 0.30);
        assert!(f15.p_rest < f0.p_rest && f30.p_rest < f15.p_rest);
        assert!(cfg.aeration.intake_gas_per_oil(0.30) > cfg.aeration.intake_gas_per_oil(0.15));
        assert!(f30.oil_total < f0.oil_total);
    }

    #[test]
    fn piston_flow_is_increasing_and_consistent() {
        let (_, d) = damper();
        let lifts = d.rest_lifts();
        let mut last = f64::NEG_INFINITY;
        let mut dp = -4e6;
        while dp <= 8e6 {
            let f = d.piston_flow(dp, &lifts, 1e9, 0.5); // h >> tau: static lifts
            assert!(f.q > last, "not increasing at {dp}");
            last = f.q;
            let e = 1.0 + 1e-4 * dp.abs();
            let num = (d.piston_flow(dp + e, &lifts, 1e9, 0.5).q
                - d.piston_flow(dp - e, &lifts, 1e9, 0.5).q)
                / (2.0 * e);
            assert!(
                (f.dq / num - 1.0).abs() < 2e-2,
                "dp {dp}: {} vs {num}",
                f.dq
            );
            dp += 1.7e5;
        }
    }
}
