//! Force-balance data with known truth, made by a small RK4 integration of
//! `m x'' = F(t) - K(x) x - R v - F_e` driven by a force sweep. It gives the
//! diagnostics engine data whose hidden effects and parameters are known
//! exactly, independent of the virtual bench and of the identification's
//! signal processing (tests and benchmarks use it; the virtual-bench and
//! reference-recording tests check the whole pipeline).

use crate::effects::Effects;
use crate::identify::ForceBalanceData;
use crate::physics::memory::Memory;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// What to simulate (all SI).
#[derive(Debug, Clone, PartialEq)]
pub struct SynthSpec {
    pub mass_kg: f64,
    /// K(x) = sum k_i x^i.
    pub k_coeffs_si: Vec<f64>,
    pub r_ns_per_m: f64,
    pub effects: Effects,
    /// Peak of the driving force (N).
    pub force_amplitude_n: f64,
    /// Log sweep of the force from `f_start_hz` to `f_end_hz` in `duration_s`
    /// (0.25 s half-cosine fades).
    pub f_start_hz: f64,
    pub f_end_hz: f64,
    pub duration_s: f64,
    pub sample_rate_hz: f64,
    /// The microphone reads `F / force_per_mic_n_per_v` (plus noise).
    pub force_per_mic_n_per_v: f64,
    /// White noise on x (m), on a (m/s^2) and on the microphone (V).
    pub laser_noise_m: f64,
    pub accel_noise_m_per_s2: f64,
    pub mic_noise_v: f64,
}

impl SynthSpec {
    /// A 4" spider like the reference recording p1 (hardening, asymmetric),
    /// swept through its large-signal resonance, 4 s at 8 kHz.
    pub fn spider() -> SynthSpec {
        SynthSpec {
            mass_kg: 0.05,
            k_coeffs_si: vec![2400.0, 1.2e5, 3.6e7, -4.8e8, 1.44e11],
            r_ns_per_m: 1.83,
            effects: Effects::default(),
            force_amplitude_n: 2.0,
            f_start_hz: 30.0,
            f_end_hz: 60.0,
            duration_s: 4.0,
            sample_rate_hz: 8000.0,
            force_per_mic_n_per_v: 0.18,
            laser_noise_m: 1e-6,
            accel_noise_m_per_s2: 0.5,
            mic_noise_v: 4e-3,
        }
    }
}

fn sweep_force(spec: &SynthSpec, t: f64) -> f64 {
    let (f1, f2, dur) = (spec.f_start_hz, spec.f_end_hz, spec.duration_s);
    if t < 0.0 || t > dur {
        return 0.0;
    }
    let l = dur / (f2 / f1).ln();
    let phase = 2.0 * std::f64::consts::PI * f1 * l * ((t / l).exp() - 1.0);
    let fade = 0.25;
    let env = if t < fade {
        0.5 - 0.5 * (std::f64::consts::PI * t / fade).cos()
    } else if t > dur - fade {
        0.5 - 0.5 * (std::f64::consts::PI * (dur - t) / fade).cos()
    } else {
        1.0
    };
    spec.force_amplitude_n * env * phase.sin()
}

/// Effect forces (without channel delay, which acts on the microphone).
fn effect_force(e: &Effects, x: f64, v: f64, xr: f64, t: f64) -> f64 {
    let mut f = 0.0;
    if let Some(c) = &e.coulomb_friction {
        f += c.force_n * (v / c.v_eps_m_per_s).tanh();
    }
    if let Some(q) = &e.quadratic_damping {
        f += q.coeff_ns2_per_m2 * v * v.abs();
    }
    if let Some(d) = &e.damping_vs_displacement {
        f += (d.r1_ns_per_m2 * x + d.r2_ns_per_m3 * x * x) * v;
    }
    if let Some(c) = &e.creep {
        f += c.k_n_per_m * (x - xr);
    }
    if let Some(s) = &e.stiffness_drift {
        f += s.dk0_dt_n_per_m_s * t * x;
    }
    f
}

fn deriv(spec: &SynthSpec, mem: &Option<Memory>, t: f64, s: [f64; 3]) -> [f64; 3] {
    let [x, v, xr] = s;
    let fm = mem.as_ref().map_or(0.0, |m| m.force(x));
    let k: f64 = spec
        .k_coeffs_si
        .iter()
        .rev()
        .fold(0.0, |acc, &c| acc * x + c);
    let f = sweep_force(spec, t)
        - k * x
        - spec.r_ns_per_m * v
        - effect_force(&spec.effects, x, v, xr, t)
        - fm;
    let xr_dot = match &spec.effects.creep {
        Some(c) => (x - xr) / c.tau_s,
        None => 0.0,
    };
    [v, f / spec.mass_kg, xr_dot]
}

/// Simulates `spec` and returns the force-balance data (noise from `seed`).
pub fn force_balance(spec: &SynthSpec, seed: u64) -> ForceBalanceData {
    let fs = spec.sample_rate_hz;
    let n = (spec.duration_s * fs).round() as usize;
    let sub = 8;
    let h = 1.0 / (fs * sub as f64);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let gauss = |sd: f64| Normal::new(0.0, sd.max(0.0)).expect("finite sd");
    let (nx, na, nm) = (
        gauss(spec.laser_noise_m),
        gauss(spec.accel_noise_m_per_s2),
        gauss(spec.mic_noise_v),
    );
    let delay = spec.effects.channel_delay.map_or(0.0, |d| d.delay_s);
    let mut s = [0.0f64; 3];
    let mut t = 0.0;
    // Hysteresis and softening: advanced after every sub-step.
    let mut mem = Memory::new(&spec.effects, fs * sub as f64);
    let mut out = ForceBalanceData {
        sample_rate_hz: fs,
        t0_s: 0.0,
        mass_kg: spec.mass_kg,
        x_m: Vec::with_capacity(n),
        v_m_per_s: Vec::with_capacity(n),
        a_m_per_s2: Vec::with_capacity(n),
        mic_v: Vec::with_capacity(n),
        laser_noise_m: spec.laser_noise_m,
        mic_noise_v: spec.mic_noise_v,
        starts_at_rest: true,
    };
    for i in 0..n {
        let ti = i as f64 / fs;
        let d = deriv(spec, &mem, ti, s);
        out.x_m.push(s[0] + nx.sample(&mut rng));
        out.v_m_per_s.push(s[1]);
        out.a_m_per_s2.push(d[1] + na.sample(&mut rng));
        out.mic_v
            .push(sweep_force(spec, ti - delay) / spec.force_per_mic_n_per_v + nm.sample(&mut rng));
        for _ in 0..sub {
            let k1 = deriv(spec, &mem, t, s);
            let s2 = add(s, k1, h / 2.0);
            let k2 = deriv(spec, &mem, t + h / 2.0, s2);
            let s3 = add(s, k2, h / 2.0);
            let k3 = deriv(spec, &mem, t + h / 2.0, s3);
            let s4 = add(s, k3, h);
            let k4 = deriv(spec, &mem, t + h, s4);
            for j in 0..3 {
                s[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
            }
            t += h;
            if let Some(m) = &mut mem {
                m.advance(s[0]);
            }
        }
    }
    out
}

fn add(s: [f64; 3], k: [f64; 3], h: f64) -> [f64; 3] {
    [s[0] + h * k[0], s[1] + h * k[1], s[2] + h * k[2]]
}
