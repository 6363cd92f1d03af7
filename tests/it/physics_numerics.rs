//! Numerical correctness of the virtual bench (issue 3): step halving
//! converges, the linear case matches the analytic transfer function, the
//! energy balance holds.

use nalgebra::{Complex, Vector4};
use springbench::effects::{
    CoulombFriction, Creep, DampingVsDisplacement, Effects, QuadraticDamping,
};
use springbench::physics::model::{idx, linear_amplitudes, BenchParams, Integrator, Model, NSTATE};
use springbench::physics::{preset, PartSpec};
use springbench::procedure::SweepSpec;
use std::f64::consts::PI;

fn all_effects() -> Effects {
    Effects {
        coulomb_friction: Some(CoulombFriction {
            force_n: 0.15,
            v_eps_m_per_s: 2e-3,
        }),
        quadratic_damping: Some(QuadraticDamping {
            coeff_ns2_per_m2: 5.0,
        }),
        damping_vs_displacement: Some(DampingVsDisplacement {
            r1_ns_per_m2: 30.0,
            r2_ns_per_m3: 5000.0,
        }),
        creep: Some(Creep {
            k_n_per_m: 300.0,
            tau_s: 0.05,
        }),
        ..Default::default()
    }
}

/// Noiseless x at the sample instants.
fn run(part: &PartSpec, bench: &BenchParams, drive: &[f64]) -> Vec<f64> {
    springbench::bench::virtual_bench::integrate(part, bench, drive).0
}

fn step_halving(part: &PartSpec, bench: &BenchParams, drive: &[f64]) -> (f64, [f64; 3]) {
    let mut bench = *bench;
    let xs: Vec<Vec<f64>> = [1, 2, 4, 8]
        .iter()
        .map(|&n| {
            bench.substeps = n;
            run(part, &bench, drive)
        })
        .collect();
    let xmax = xs[3].iter().fold(0.0f64, |a, x| a.max(x.abs()));
    let err = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max)
    };
    (
        xmax,
        [
            err(&xs[0], &xs[3]),
            err(&xs[1], &xs[3]),
            err(&xs[2], &xs[3]),
        ],
    )
}

#[test]
fn step_halving_converges() {
    // Large signal: 1.5 s rising sweep through the resonance.
    let drive = SweepSpec::new(25.0, 70.0, 1.5, 60.0).samples(48000.0);
    let plain = preset("spider_4in").unwrap();
    let mut with_fx = plain.clone();
    with_fx.effects = all_effects();
    let mut le = BenchParams::default();
    le.exciter.le_h = 1e-3;
    for (what, part, bench) in [
        ("plain part, Le = 0", &plain, BenchParams::default()),
        ("all effects, Le = 1 mH", &with_fx, le),
    ] {
        let (xmax, [e1, e2, e4]) = step_halving(part, &bench, &drive);
        eprintln!(
            "step halving, {what}: max |x_h - x_h/8| = {e1:.3e}, {e2:.3e}, {e4:.3e} m for h = 1/48000, 1/96000, 1/192000 s (xmax {xmax:.3e} m)"
        );
        assert!(xmax > 3e-3, "large signal: {xmax}");
        // One step per sample is accurate to 1e-5 of the excursion ...
        assert!(e1 < 1e-5 * xmax, "{e1}");
        // ... and the error falls at least like h^4 per halving (16; 15 measured against h/8).
        assert!(
            e1 / e2 > 12.0 && e2 / e4 > 12.0,
            "ratios {} {}",
            e1 / e2,
            e2 / e4
        );
    }
}

/// Steady-state complex amplitudes [I, Xd, X, P] for a unit cosine drive
/// (`physics::model::linear_amplitudes`, at the part's K(0)).
fn analytic(part: &PartSpec, b: &BenchParams, f_hz: f64) -> Vector4<Complex<f64>> {
    linear_amplitudes(part, b, part.k_coeffs_si[0], f_hz).expect("a regular system")
}

#[test]
fn linear_case_matches_the_analytic_transfer_function() {
    for name in ["spider_4in", "cone_18in"] {
        let mut part = preset(name).unwrap();
        part.k_coeffs_si.truncate(1);
        let mut b = BenchParams::default();
        b.box_.adiabatic = false;
        b.exciter.le_h = 0.5e-3;
        let fs = b.sample_rate_hz;
        for f in [7.0, part.f0_hz(), 35.0, 90.0] {
            let a = analytic(&part, &b, f);
            let w = 2.0 * PI * f;
            let at = |z: Complex<f64>, t: f64| (z * Complex::new(0.0, w * t).exp()).re;
            let jw = Complex::new(0.0, w);
            let mut sim = Integrator::new(Model::new(&part, &b), fs, 1);
            // Start on the steady state: no transient to wait for.
            let mut s = [0.0; NSTATE];
            s[idx::I] = a[0].re;
            s[idx::XD] = a[1].re;
            s[idx::VD] = (jw * a[1]).re;
            s[idx::X] = a[2].re;
            s[idx::V] = (jw * a[2]).re;
            s[idx::P] = a[3].re;
            sim.state = s;
            let n = (0.3 * fs) as usize;
            let (mut ex, mut ep) = (0.0f64, 0.0f64);
            for k in 0..n {
                let t = k as f64 / fs;
                ex = ex.max((sim.state[idx::X] - at(a[2], t)).abs());
                ep = ep.max((sim.state[idx::P] - at(a[3], t)).abs());
                sim.step((w * t).cos(), (w * (t + 1.0 / fs)).cos());
            }
            let (rx, rp) = (ex / a[2].norm(), ep / a[3].norm());
            eprintln!("{name} at {f:.1} Hz: |X/U| {:.4e} m/V, |P/U| {:.4e} Pa/V, max error {rx:.1e} (x), {rp:.1e} (p)", a[2].norm(), a[3].norm());
            // The simulator interpolates the drive linearly between samples,
            // which by itself differs from the cosine by O((w/fs)^2 / 12), 1e-5 at 90 Hz.
            assert!(rx < 1e-4 && rp < 1e-4, "{name} {f} Hz: {rx} {rp}");
        }
    }
}

/// Input energy minus dissipated energy equals the change of the stored
/// energy (trapezoid over the samples).
fn energy_residual(part: &PartSpec, b: &BenchParams, drive: &[f64]) -> (f64, f64) {
    let model = Model::new(part, b);
    let mut sim = Integrator::new(model.clone(), b.sample_rate_hz, b.substeps);
    let dt = 1.0 / b.sample_rate_hz;
    let e0 = model.energy(0.0, &sim.state, drive[0]);
    let (mut e_in, mut e_diss) = (0.0, 0.0);
    let mut prev = e0;
    for k in 0..drive.len() - 1 {
        sim.step(drive[k], drive[k + 1]);
        let e = model.energy(sim.t, &sim.state, drive[k + 1]);
        e_in += 0.5 * dt * (prev.input_w + e.input_w);
        e_diss += 0.5 * dt * (prev.dissipated_w + e.dissipated_w);
        prev = e;
    }
    let resid = e_in - e_diss - (prev.stored_j - e0.stored_j);
    (resid, e_in)
}

#[test]
fn energy_balance_holds() {
    let drive = SweepSpec::new(20.0, 80.0, 1.5, 30.0).samples(48000.0);
    let mut part = preset("spider_4in").unwrap();
    part.effects = all_effects();
    // A second mechanical mode inside the sweep (its spring and damper count).
    part.second_mode = Some(springbench::physics::SecondMode {
        mass_kg: 0.005,
        f_hz: 60.0,
        q: 5.0,
    });
    // (a) adiabatic box without leak (the gas energy is exact), all dissipative effects,
    // a second mode, Le.
    let mut b = BenchParams::default();
    b.box_.leak_tau_s = f64::INFINITY;
    b.exciter.le_h = 1e-3;
    let (r, e_in) = energy_residual(&part, &b, &drive);
    eprintln!("adiabatic, no leak: input {e_in:.4} J, residual {r:.3e} J");
    assert!(r.abs() < 1e-5 * e_in, "{r} of {e_in}");
    // (b) linear air spring with leak, large cone.
    let mut part = preset("cone_18in").unwrap();
    part.effects = all_effects();
    let mut b = BenchParams::default();
    b.box_.adiabatic = false;
    let drive = SweepSpec::new(8.0, 30.0, 1.5, 10.0).samples(48000.0);
    let (r, e_in) = energy_residual(&part, &b, &drive);
    eprintln!("linear box with leak: input {e_in:.4} J, residual {r:.3e} J");
    assert!(r.abs() < 1e-5 * e_in, "{r} of {e_in}");
}
