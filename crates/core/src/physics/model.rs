//! The lumped model of the pneumatic bench and its fixed-step RK4 integrator.
//!
//! State (SI): part displacement `x` (positive out of the box) and velocity
//! `v`; exciter cone displacement `xd` (positive into the box) and velocity
//! `vd`; box gauge pressure `p`; exciter current `i` (only with `Le > 0`,
//! otherwise algebraic); creep state `xr` (standard linear solid).
//!
//! Equations:
//! - exciter: `Le i' = u - Re i - Bl vd`, `Mmd vd' = Bl i - Rmd vd - Kmd xd - Sd p`
//!   (positive current pushes the cone into the box; the box pressure pushes it out)
//! - part: `m v' = Ss p - R v - K(x) x - F_effects`
//! - box volume `V = V0 - Sd xd + Ss x`; adiabatic air spring
//!   `p0 + p = p0 (mu V0/V)^gamma` whose air mass `mu` (relative) leaks out
//!   through RAL: `mu'/mu = -p CAB/(tau_leak V)`, `tau_leak = RAL CAB`, so
//!   `p' = -gamma (p0 + p)/V (V' + p CAB/tau_leak)`; linear box:
//!   `p' = -gamma p0 V'/V0 - p/tau_leak`.
//!
//! The drive is given per sample; between samples it is interpolated linearly.

use crate::effects::Effects;
use serde::{Deserialize, Serialize};

/// Exciter loudspeaker (voltage driven).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Exciter {
    pub re_ohm: f64,
    /// Voice-coil inductance (H); 0 makes the current algebraic.
    #[serde(default)]
    pub le_h: f64,
    pub bl_tm: f64,
    pub mmd_kg: f64,
    pub rmd_ns_per_m: f64,
    pub kmd_n_per_m: f64,
    pub sd_m2: f64,
}

/// The closed box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxParams {
    pub volume_m3: f64,
    pub gamma: f64,
    pub p0_pa: f64,
    /// Leak time constant RAL*CAB (s); `f64::INFINITY` (or absent in JSON) = no leak.
    #[serde(default = "inf")]
    pub leak_tau_s: f64,
    /// Adiabatic (nonlinear) air spring; false = linearised `p = -gamma p0 dV/V0`.
    pub adiabatic: bool,
}

fn inf() -> f64 {
    f64::INFINITY
}

/// Laser triangulation sensor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Laser {
    /// White noise (m RMS).
    pub noise_m: f64,
    /// Measuring range +-range_m; beyond it the sample is flagged out of range.
    pub range_m: f64,
    /// Quantisation step (m); 0 = none.
    #[serde(default)]
    pub quantisation_m: f64,
    /// Delay of the laser path (s).
    #[serde(default)]
    pub delay_s: f64,
}

/// Microphone in the box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Microphone {
    pub gain_v_per_pa: f64,
    /// White noise referred to the pressure (Pa RMS).
    pub noise_pa: f64,
    /// Delay of the microphone path (s), in addition to the `channel_delay` effect.
    #[serde(default)]
    pub delay_s: f64,
}

/// Everything of the bench except the part.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchParams {
    pub sample_rate_hz: f64,
    /// RK4 steps per sample (1 or 2 is plenty at 48 kHz).
    pub substeps: u32,
    pub exciter: Exciter,
    #[serde(rename = "box")]
    pub box_: BoxParams,
    pub laser: Laser,
    pub microphone: Microphone,
    /// ADC full scale of the microphone and drive inputs (V peak); beyond it the samples clip.
    pub adc_full_scale_v: f64,
    /// Bits of the converter that captures all three channels (the laser's
    /// analog output over +-`laser.range_m`, the microphone and the drive
    /// loopback over +-`adc_full_scale_v`), as a commercial bench wires it.
    /// Every captured sample is one of its codes; the store keeps exactly
    /// those (FLAC, decision 0013).
    #[serde(default = "default_converter_bits")]
    pub converter_bits: u32,
}

fn default_converter_bits() -> u32 {
    24
}

impl Default for BenchParams {
    /// The bench of the independent reference simulator
    /// (`shared/data/reference-recordings/README.md` and its truth.json `bench`).
    fn default() -> Self {
        BenchParams {
            sample_rate_hz: 48000.0,
            substeps: 1,
            exciter: Exciter {
                re_ohm: 5.5,
                le_h: 0.0,
                bl_tm: 20.0,
                mmd_kg: 0.25,
                rmd_ns_per_m: 3.0,
                kmd_n_per_m: 3000.0,
                sd_m2: 0.115,
            },
            box_: BoxParams {
                volume_m3: 0.095,
                gamma: 1.4,
                p0_pa: 101325.0,
                leak_tau_s: 1.0,
                adiabatic: true,
            },
            laser: Laser {
                noise_m: 1e-6,
                range_m: 0.025,
                quantisation_m: 0.0,
                delay_s: 0.0,
            },
            microphone: Microphone {
                gain_v_per_pa: 0.0137,
                noise_pa: 0.3,
                delay_s: 0.0,
            },
            adc_full_scale_v: 100.0,
            converter_bits: default_converter_bits(),
        }
    }
}

impl BenchParams {
    /// One-line error naming the first implausible field.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |n: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("bench.{n} must be a positive number, got {v}"))
            }
        };
        let nonneg = |n: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(format!("bench.{n} must be >= 0, got {v}"))
            }
        };
        pos("sample_rate_hz", self.sample_rate_hz)?;
        if self.substeps == 0 || self.substeps > 64 {
            return Err(format!(
                "bench.substeps must be 1..=64, got {}",
                self.substeps
            ));
        }
        let e = &self.exciter;
        pos("exciter.re_ohm", e.re_ohm)?;
        nonneg("exciter.le_h", e.le_h)?;
        pos("exciter.bl_tm", e.bl_tm)?;
        pos("exciter.mmd_kg", e.mmd_kg)?;
        nonneg("exciter.rmd_ns_per_m", e.rmd_ns_per_m)?;
        nonneg("exciter.kmd_n_per_m", e.kmd_n_per_m)?;
        pos("exciter.sd_m2", e.sd_m2)?;
        let b = &self.box_;
        pos("box.volume_m3", b.volume_m3)?;
        pos("box.gamma", b.gamma)?;
        pos("box.p0_pa", b.p0_pa)?;
        if b.leak_tau_s.is_nan() || b.leak_tau_s <= 0.0 {
            return Err(format!(
                "bench.box.leak_tau_s must be > 0 (inf = no leak), got {}",
                b.leak_tau_s
            ));
        }
        nonneg("laser.noise_m", self.laser.noise_m)?;
        pos("laser.range_m", self.laser.range_m)?;
        nonneg("laser.quantisation_m", self.laser.quantisation_m)?;
        nonneg("laser.delay_s", self.laser.delay_s)?;
        pos("microphone.gain_v_per_pa", self.microphone.gain_v_per_pa)?;
        nonneg("microphone.noise_pa", self.microphone.noise_pa)?;
        nonneg("microphone.delay_s", self.microphone.delay_s)?;
        pos("adc_full_scale_v", self.adc_full_scale_v)?;
        if !(8..=24).contains(&self.converter_bits) {
            return Err(format!(
                "bench.converter_bits must be 8..=24, got {}",
                self.converter_bits
            ));
        }
        Ok(())
    }
}

/// Number of state variables.
pub const NSTATE: usize = 9;
/// Indices into the state vector.
pub mod idx {
    pub const X: usize = 0;
    pub const V: usize = 1;
    pub const XD: usize = 2;
    pub const VD: usize = 3;
    pub const P: usize = 4;
    pub const I: usize = 5;
    pub const XR: usize = 6;
    /// Displacement and velocity of the second mode's mass (`PartSpec::second_mode`).
    pub const X2: usize = 7;
    pub const V2: usize = 8;
}

/// Plain-number view of the part and the bench used inside the derivative.
#[derive(Debug, Clone)]
pub struct Model {
    /// Mass of the main body (the moving mass less a second mode's mass).
    pub m: f64,
    /// Second mode: mass (kg), spring (N/m), damper (N s/m); m2 = 0: none.
    pub m2: f64,
    pub k2: f64,
    pub r2: f64,
    /// k_0..k_11, zero-padded (a fixed array keeps the inner loop short).
    pub k: [f64; 12],
    /// Highest non-zero power + 1.
    k_len: usize,
    pub r: f64,
    pub ss: f64,
    pub fx: Effects,
    pub ex: Exciter,
    pub bx: BoxParams,
    /// gamma p0 / V0
    kbox: f64,
    inv_tau_leak: f64,
    inv_m: f64,
    inv_mmd: f64,
    inv_re: f64,
    inv_le: f64,
    /// CAB / tau_leak = V0 / (gamma p0 tau_leak) (m^3 / (Pa s)).
    leak_cab_per_tau: f64,
    /// Any force effect present (skip their evaluation otherwise).
    any_force_effect: bool,
    inv_m2: f64,
    /// Hysteresis and reversible softening: states that follow the path of
    /// x, advanced once per sample (`super::memory`); None without them.
    pub memory: Option<super::memory::Memory>,
    /// Ageing (`ageing.rs`): the stiffness at rest lost so far (N/m) and
    /// 1/x_w^4 of its shape; the elastic force is K(x) x - loss w(x) x.
    ageing_loss_n_per_m: f64,
    ageing_inv_width4: f64,
    /// A defect's collapse (`ageing::Collapse`): the fraction of K(x) lost
    /// over the whole stroke.
    ageing_collapse: f64,
}

/// Instantaneous powers (W) and stored energies (J) for the energy balance.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Energy {
    /// Electrical input power u*i.
    pub input_w: f64,
    /// All dissipated power (Re, Rmd, R, leak, effects).
    pub dissipated_w: f64,
    /// Kinetic + spring + magnetic + gas energy.
    pub stored_j: f64,
}

/// w(x) = exp(-(x/x_w)^4) from `inv_width4` = 1/x_w^4: the shape of the
/// stiffness an ageing part loses near rest (`physics::ageing`).
#[inline]
pub fn ageing_shape(x_m: f64, inv_width4: f64) -> f64 {
    let u = x_m * x_m;
    (-(u * u * inv_width4)).exp()
}

/// The linear model's steady state for a unit cosine drive at `f_hz`: the
/// complex amplitudes of [I (A), Xd (m), X (m), P (Pa)] per volt, the part's
/// stiffness `k_n_per_m` (its K(0), or an effective stiffness at a level)
/// and its damping R, the box's air spring linearised. None when the
/// system is singular there.
pub fn linear_amplitudes(
    part: &super::PartSpec,
    bench: &BenchParams,
    k_n_per_m: f64,
    f_hz: f64,
) -> Option<nalgebra::Vector4<nalgebra::Complex<f64>>> {
    use nalgebra::{Complex, Matrix4, Vector4};
    let w = 2.0 * std::f64::consts::PI * f_hz;
    let j = Complex::new(0.0, 1.0);
    let c = |v: f64| Complex::new(v, 0.0);
    let e = &bench.exciter;
    let bx = &bench.box_;
    let kbox = bx.gamma * bx.p0_pa / bx.volume_m3;
    #[rustfmt::skip]
    let m = Matrix4::new(
        c(e.re_ohm) + j * w * e.le_h, j * w * e.bl_tm, c(0.0), c(0.0),
        c(-e.bl_tm), c(-w * w * e.mmd_kg + e.kmd_n_per_m) + j * w * e.rmd_ns_per_m, c(0.0), c(e.sd_m2),
        c(0.0), c(0.0), c(-w * w * part.moving_mass_kg + k_n_per_m) + j * w * part.r_ns_per_m, c(-part.ss_m2),
        c(0.0), -j * w * kbox * e.sd_m2, j * w * kbox * part.ss_m2, j * w + 1.0 / bx.leak_tau_s,
    );
    m.lu().solve(&Vector4::new(c(1.0), c(0.0), c(0.0), c(0.0)))
}

impl Model {
    pub fn new(part: &super::PartSpec, bench: &BenchParams) -> Model {
        let bx = bench.box_;
        let mut k = [0.0; 12];
        let k_len = part.k_coeffs_si.len().min(12);
        k[..k_len].copy_from_slice(&part.k_coeffs_si[..k_len]);
        let fx = part.effects;
        let any_force_effect = fx.coulomb_friction.is_some()
            || fx.quadratic_damping.is_some()
            || fx.damping_vs_displacement.is_some()
            || fx.creep.is_some()
            || fx.stiffness_drift.is_some()
            || fx.hysteresis.is_some()
            || fx.reversible_softening.is_some();
        let ex = bench.exciter;
        let (m2, (k2, r2)) = part
            .second_mode
            .map_or((0.0, (0.0, 0.0)), |m| (m.mass_kg, m.spring_damper()));
        let m1 = part.moving_mass_kg - m2;
        Model {
            m: m1,
            m2,
            k2,
            r2,
            inv_m2: if m2 > 0.0 { 1.0 / m2 } else { 0.0 },
            k,
            k_len,
            r: part.r_ns_per_m,
            ss: part.ss_m2,
            fx: part.effects,
            ex: bench.exciter,
            bx,
            kbox: bx.gamma * bx.p0_pa / bx.volume_m3,
            inv_tau_leak: if bx.leak_tau_s.is_finite() {
                1.0 / bx.leak_tau_s
            } else {
                0.0
            },
            leak_cab_per_tau: if bx.leak_tau_s.is_finite() {
                bx.volume_m3 / (bx.gamma * bx.p0_pa * bx.leak_tau_s)
            } else {
                0.0
            },
            inv_m: 1.0 / m1,
            inv_mmd: 1.0 / ex.mmd_kg,
            inv_re: 1.0 / ex.re_ohm,
            inv_le: if ex.le_h > 0.0 { 1.0 / ex.le_h } else { 0.0 },
            any_force_effect,
            memory: super::memory::Memory::new(&fx, bench.sample_rate_hz),
            ageing_loss_n_per_m: 0.0,
            ageing_inv_width4: part.ageing.map_or(0.0, |a| a.width_m.powi(-4)),
            ageing_collapse: 0.0,
        }
    }

    /// Sets the stiffness at rest the part's ageing has removed so far
    /// (N/m, `AgeingParams::lost_k_n_per_m`); no effect on a part without
    /// ageing parameters.
    pub fn set_ageing_loss(&mut self, loss_n_per_m: f64) {
        if self.ageing_inv_width4 > 0.0 && loss_n_per_m > 0.0 {
            self.ageing_loss_n_per_m = loss_n_per_m;
            self.any_force_effect = true;
        }
    }

    /// Sets the fraction of K(x) a defect's collapse has removed so far
    /// (`AgeingParams::collapse_fraction`).
    pub fn set_ageing_collapse(&mut self, fraction: f64) {
        if fraction > 0.0 {
            self.ageing_collapse = fraction;
            self.any_force_effect = true;
        }
    }

    /// The elastic restoring force of the part (N): K(x) x less ageing's loss.
    #[inline]
    pub fn elastic_force(&self, x: f64) -> f64 {
        let mut k = self.stiffness(x);
        if self.ageing_collapse > 0.0 {
            k *= 1.0 - self.ageing_collapse;
        }
        if self.ageing_loss_n_per_m > 0.0 {
            k -= self.ageing_loss_n_per_m * ageing_shape(x, self.ageing_inv_width4);
        }
        k * x
    }

    /// K(x) (N/m).
    #[inline]
    pub fn stiffness(&self, x: f64) -> f64 {
        if self.k_len <= 8 {
            // Estrin's scheme on the zero-padded coefficients: a dependency
            // chain of 3 multiply-adds instead of 8 (this sits on the RK4
            // critical path four times per sample).
            let k = &self.k;
            let x2 = x * x;
            let x4 = x2 * x2;
            let b0 = (k[0] + k[1] * x) + (k[2] + k[3] * x) * x2;
            let b1 = (k[4] + k[5] * x) + (k[6] + k[7] * x) * x2;
            return b0 + b1 * x4;
        }
        let mut acc = 0.0;
        for &c in self.k[..self.k_len].iter().rev() {
            acc = acc * x + c;
        }
        acc
    }

    /// Force of the effects on the part (opposing, N), without creep's state derivative.
    #[inline]
    fn effect_force(&self, t: f64, x: f64, v: f64, xr: f64) -> f64 {
        let mut f = 0.0;
        let fx = &self.fx;
        if let Some(c) = &fx.coulomb_friction {
            f += c.force_n * (v / c.v_eps_m_per_s).tanh();
        }
        if let Some(q) = &fx.quadratic_damping {
            f += q.coeff_ns2_per_m2 * v * v.abs();
        }
        if let Some(d) = &fx.damping_vs_displacement {
            f += (d.r1_ns_per_m2 * x + d.r2_ns_per_m3 * x * x) * v;
        }
        if let Some(c) = &fx.creep {
            f += c.k_n_per_m * (x - xr);
        }
        if let Some(s) = &fx.stiffness_drift {
            f += s.dk0_dt_n_per_m_s * t * x;
        }
        if let Some(m) = &self.memory {
            f += m.force(x);
        }
        if self.ageing_loss_n_per_m > 0.0 {
            f -= self.ageing_loss_n_per_m * ageing_shape(x, self.ageing_inv_width4) * x;
        }
        if self.ageing_collapse > 0.0 {
            f -= self.ageing_collapse * self.stiffness(x) * x;
        }
        f
    }

    #[inline]
    fn current(&self, s: &[f64; NSTATE], u: f64) -> f64 {
        if self.ex.le_h > 0.0 {
            s[idx::I]
        } else {
            (u - self.ex.bl_tm * s[idx::VD]) * self.inv_re
        }
    }

    /// Time derivative of the state at time `t` with drive `u`.
    #[inline(always)]
    pub fn deriv(&self, t: f64, s: &[f64; NSTATE], u: f64) -> [f64; NSTATE] {
        let (x, v, xd, vd, p, xr) = (
            s[idx::X],
            s[idx::V],
            s[idx::XD],
            s[idx::VD],
            s[idx::P],
            s[idx::XR],
        );
        let ex = &self.ex;
        let i = self.current(s, u);
        let di = if ex.le_h > 0.0 {
            (u - ex.re_ohm * i - ex.bl_tm * vd) * self.inv_le
        } else {
            0.0
        };
        let fe = if self.any_force_effect {
            self.effect_force(t, x, v, xr)
        } else {
            0.0
        };
        // Second mode: the force of its spring and damper on the main body.
        let (v2, f2) = if self.m2 > 0.0 {
            let v2 = s[idx::V2];
            (v2, self.k2 * (x - s[idx::X2]) + self.r2 * (v - v2))
        } else {
            (0.0, 0.0)
        };
        let a = (self.ss * p - self.r * v - self.stiffness(x) * x - fe - f2) * self.inv_m;
        let ad = (ex.bl_tm * i - ex.rmd_ns_per_m * vd - ex.kmd_n_per_m * xd - ex.sd_m2 * p)
            * self.inv_mmd;
        let dvol = -ex.sd_m2 * vd + self.ss * v;
        let dp = if self.bx.adiabatic {
            // pabs = p0 (mu V0/V)^gamma with mu the air mass relative to the
            // start; the leak carries air of the box's density out at p/RAL:
            // mu'/mu = -p CAB / (tau V).
            let vol = self.bx.volume_m3 - ex.sd_m2 * xd + self.ss * x;
            -self.bx.gamma * (self.bx.p0_pa + p) / vol * (dvol + p * self.leak_cab_per_tau)
        } else {
            -self.kbox * dvol - p * self.inv_tau_leak
        };
        let dxr = match &self.fx.creep {
            Some(c) => (x - xr) / c.tau_s,
            None => 0.0,
        };
        [v, a, vd, ad, dp, di, dxr, v2, f2 * self.inv_m2]
    }

    /// Powers and stored energy at a state (for the energy-balance test;
    /// an aged part's lost spring energy is not in it).
    pub fn energy(&self, t: f64, s: &[f64; NSTATE], u: f64) -> Energy {
        let (x, v, xd, vd, p, xr) = (
            s[idx::X],
            s[idx::V],
            s[idx::XD],
            s[idx::VD],
            s[idx::P],
            s[idx::XR],
        );
        let ex = &self.ex;
        let i = self.current(s, u);
        // Spring energy of the part: integral of K(x) x dx = sum k_j x^(j+2)/(j+2).
        let mut spring = 0.0;
        for (j, &c) in self.k[..self.k_len].iter().enumerate() {
            spring += c * x.powi(j as i32 + 2) / (j as f64 + 2.0);
        }
        let mut stored = 0.5 * self.m * v * v
            + spring
            + 0.5 * ex.mmd_kg * vd * vd
            + 0.5 * ex.kmd_n_per_m * xd * xd
            + 0.5 * ex.le_h * i * i;
        let mut diss = ex.re_ohm * i * i + ex.rmd_ns_per_m * vd * vd + self.r * v * v;
        let bx = &self.bx;
        if bx.adiabatic {
            // Internal energy of the gas minus the work of the atmosphere outside.
            let vol = bx.volume_m3 - ex.sd_m2 * xd + self.ss * x;
            let pabs = bx.p0_pa + p;
            stored += (pabs * vol - bx.p0_pa * bx.volume_m3) / (bx.gamma - 1.0)
                + bx.p0_pa * (vol - bx.volume_m3);
            // Only exact without a leak (the leak changes the air mass).
            diss += 0.0;
        } else {
            stored += 0.5 * p * p / self.kbox;
            diss += p * p * self.inv_tau_leak / self.kbox;
        }
        let fx = &self.fx;
        if let Some(c) = &fx.coulomb_friction {
            diss += c.force_n * (v / c.v_eps_m_per_s).tanh() * v;
        }
        if let Some(q) = &fx.quadratic_damping {
            diss += q.coeff_ns2_per_m2 * v * v * v.abs();
        }
        if let Some(d) = &fx.damping_vs_displacement {
            diss += (d.r1_ns_per_m2 * x + d.r2_ns_per_m3 * x * x) * v * v;
        }
        if let Some(c) = &fx.creep {
            stored += 0.5 * c.k_n_per_m * (x - xr) * (x - xr);
            diss += c.k_n_per_m * (x - xr) * (x - xr) / c.tau_s;
        }
        if self.m2 > 0.0 {
            let (x2, v2) = (s[idx::X2], s[idx::V2]);
            stored += 0.5 * self.m2 * v2 * v2 + 0.5 * self.k2 * (x - x2) * (x - x2);
            diss += self.r2 * (v - v2) * (v - v2);
        }
        let _ = t;
        Energy {
            input_w: u * i,
            dissipated_w: diss,
            stored_j: stored,
        }
    }
}

/// Fixed-step RK4 integration of [`Model`], one sample at a time.
#[derive(Debug, Clone)]
pub struct Integrator {
    pub model: Model,
    pub state: [f64; NSTATE],
    /// Time of `state` (s) since the start of the recording.
    pub t: f64,
    dt_sample: f64,
    substeps: u32,
}

impl Integrator {
    pub fn new(mut model: Model, sample_rate_hz: f64, substeps: u32) -> Integrator {
        if let Some(m) = &mut model.memory {
            m.set_sample_rate(sample_rate_hz);
        }
        Integrator {
            model,
            state: [0.0; NSTATE],
            t: 0.0,
            dt_sample: 1.0 / sample_rate_hz,
            substeps: substeps.max(1),
        }
    }

    /// Advances one sample period; the drive goes linearly from `u0` to `u1`.
    #[inline]
    pub fn step(&mut self, u0: f64, u1: f64) {
        if self.substeps == 1 {
            rk4(
                &self.model,
                self.t,
                self.dt_sample,
                &mut self.state,
                u0,
                0.5 * (u0 + u1),
                u1,
            );
            self.t += self.dt_sample;
            self.advance_memory();
            return;
        }
        let n = self.substeps;
        let h = self.dt_sample / n as f64;
        let t0 = self.t;
        for k in 0..n {
            let a = k as f64 / n as f64;
            let b = (k as f64 + 0.5) / n as f64;
            let c = (k as f64 + 1.0) / n as f64;
            let ua = u0 + (u1 - u0) * a;
            let ub = u0 + (u1 - u0) * b;
            let uc = u0 + (u1 - u0) * c;
            let t = t0 + a * self.dt_sample;
            rk4(&self.model, t, h, &mut self.state, ua, ub, uc);
        }
        self.t = t0 + self.dt_sample;
        self.advance_memory();
    }

    /// The path-following states move to the end of the sample.
    #[inline]
    fn advance_memory(&mut self) {
        if let Some(m) = &mut self.model.memory {
            m.advance(self.state[idx::X]);
        }
    }
}

#[inline(always)]
fn rk4(m: &Model, t: f64, h: f64, s: &mut [f64; NSTATE], ua: f64, ub: f64, uc: f64) {
    let add = |s: &[f64; NSTATE], k: &[f64; NSTATE], f: f64| {
        let mut o = *s;
        for j in 0..NSTATE {
            o[j] += f * k[j];
        }
        o
    };
    let k1 = m.deriv(t, s, ua);
    let k2 = m.deriv(t + 0.5 * h, &add(s, &k1, 0.5 * h), ub);
    let k3 = m.deriv(t + 0.5 * h, &add(s, &k2, 0.5 * h), ub);
    let k4 = m.deriv(t + h, &add(s, &k3, h), uc);
    for j in 0..NSTATE {
        s[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
    }
}
