//! Agreement of the virtual bench with the independent simulator that made
//! `shared/data/reference-recordings` (issue 3): same part, same bench, same
//! stimulus; displacement within 1 % RMS of p1's recorded x, noise aside.

use springbench::bench::virtual_bench::integrate;
use springbench::physics::{BenchParams, PartSpec};
use springbench::procedure::SweepSpec;
use springbench::recording::RecordingSet;
use springbench::recording::RecordingSetFiles;
use std::path::PathBuf;

fn refdir(case: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/reference-recordings")
        .join(case)
}

struct Case {
    part: PartSpec,
    bench: BenchParams,
    pre: SweepSpec,
    main: SweepSpec,
    set: RecordingSet,
    truth: serde_json::Value,
}

fn load(case: &str) -> Case {
    let dir = refdir(case);
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("truth.json")).unwrap()).unwrap();
    let set = RecordingSet::read_dir(&dir).unwrap();
    let f = |v: &serde_json::Value| v.as_f64().unwrap();
    let part = PartSpec {
        name: case.into(),
        moving_mass_kg: f(&truth["bench"]["mass_kg"]),
        k_coeffs_si: truth["k_coeffs_si"]
            .as_array()
            .unwrap()
            .iter()
            .map(f)
            .collect(),
        r_ns_per_m: f(&truth["R_ns_per_m"]),
        ss_m2: f(&truth["ss_m2"]),
        effects: serde_json::from_value(truth["effects"].clone()).unwrap(),
        laser_noise_m: None,
        second_mode: None,
        ageing: None,
    };
    let mut bench = BenchParams::default();
    let b = &truth["bench"];
    let e = &b["exciter"];
    bench.exciter.sd_m2 = f(&e["sd"]);
    bench.exciter.mmd_kg = f(&e["mmd"]);
    bench.exciter.kmd_n_per_m = f(&e["kmd"]);
    bench.exciter.rmd_ns_per_m = f(&e["rmd"]);
    bench.exciter.bl_tm = f(&e["bl"]);
    bench.exciter.re_ohm = f(&e["re"]);
    bench.box_.volume_m3 = f(&b["box_l"]) * 1e-3;
    bench.box_.leak_tau_s = f(&b["leak_tau_s"]);
    bench.box_.adiabatic = truth["adiabatic"].as_bool().unwrap();
    bench.microphone.gain_v_per_pa = f(&truth["mic_gain"]);
    assert_eq!(
        bench,
        BenchParams::default(),
        "the default bench is the reference simulator's"
    );
    let sweep = |k: &str| {
        let a: Vec<f64> = truth[k].as_array().unwrap().iter().map(f).collect();
        SweepSpec::new(a[0], a[1], a[2], a[3])
    };
    Case {
        part,
        bench,
        pre: sweep("pre_sweep"),
        main: sweep("main_sweep"),
        set,
        truth,
    }
}

/// RMS of (sim - rec) relative to RMS(rec), with the laser's white noise
/// (known variance) removed from the difference in quadrature.
fn rel_rms_noise_aside(sim: &[f64], rec: &[f64], noise_m: f64) -> (f64, f64) {
    let n = rec.len() as f64;
    let ms_d: f64 = sim
        .iter()
        .zip(rec)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        / n;
    let ms_r: f64 = rec.iter().map(|b| b * b).sum::<f64>() / n;
    let raw = (ms_d / ms_r).sqrt();
    let aside = ((ms_d - noise_m * noise_m).max(0.0) / ms_r).sqrt();
    (raw, aside)
}

fn compare(case: &str) -> Vec<(String, f64, f64)> {
    let c = load(case);
    let fs = c.set.meta.sample_rate_hz;
    let mut out = Vec::new();
    for (name, spec, rec) in [("pre", c.pre, &c.set.pre), ("main", c.main, &c.set.main)] {
        let drive = spec.samples(fs);
        assert_eq!(drive.len(), rec.len(), "{case} {name}: length");
        // The rebuilt stimulus is the recorded drive channel (float32).
        let rd = rec.drive_v.as_ref().unwrap();
        let dmax = drive
            .iter()
            .zip(rd)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            dmax < 1e-5 * spec.amplitude_v.max(1.0),
            "{case} {name}: drive differs by {dmax}"
        );
        let (x, _p) = integrate(&c.part, &c.bench, &drive);
        let (raw, aside) = rel_rms_noise_aside(&x, &rec.displacement_m, c.bench.laser.noise_m);
        out.push((name.to_string(), raw, aside));
    }
    let _ = &c.truth;
    out
}

#[test]
fn p1_spider_displacement_agrees_with_the_independent_simulator() {
    for (name, raw, aside) in compare("p1_spider") {
        eprintln!(
            "p1_spider {name}: x differs by {:.4} % RMS ({:.4} % with the laser noise)",
            aside * 100.0,
            raw * 100.0
        );
        assert!(aside < 0.01, "p1 {name}: {:.3} % RMS", aside * 100.0);
    }
}

#[test]
fn p2_friction_and_p3_cone_agree_too() {
    for case in ["p2_spider_friction", "p3_cone"] {
        for (name, raw, aside) in compare(case) {
            eprintln!(
                "{case} {name}: x differs by {:.4} % RMS ({:.4} % with the laser noise)",
                aside * 100.0,
                raw * 100.0
            );
            assert!(aside < 0.01, "{case} {name}: {:.3} % RMS", aside * 100.0);
        }
    }
}

/// Which modelling choice explains the remaining difference on p1's main
/// sweep (figures for docs/virtual-bench.md): `cargo test --release --test
/// physics_reference -- --ignored --nocapture`.
#[test]
#[ignore = "investigation for the docs, prints figures"]
fn p1_main_difference_by_model_variant() {
    let c = load("p1_spider");
    let fs = c.set.meta.sample_rate_hz;
    let drive = c.main.samples(fs);
    let rec = &c.set.main.displacement_m;
    let mut variants: Vec<(&str, BenchParams)> = vec![("default", c.bench)];
    let mut b = c.bench;
    b.substeps = 4;
    variants.push(("4 substeps", b));
    let mut b = c.bench;
    b.box_.adiabatic = false;
    variants.push(("linear air spring", b));
    let mut b = c.bench;
    b.box_.leak_tau_s = f64::INFINITY;
    variants.push(("no leak", b));
    for (name, b) in variants {
        let (x, _) = integrate(&c.part, &b, &drive);
        let (raw, aside) = rel_rms_noise_aside(&x, rec, b.laser.noise_m);
        eprintln!(
            "p1 main, {name}: {:.4} % RMS ({:.4} % raw)",
            aside * 100.0,
            raw * 100.0
        );
    }
    // Time shift by a fraction of a sample, amplitude scale.
    let (x, _) = integrate(&c.part, &c.bench, &drive);
    for shift in [-1.0, -0.5, -0.25, 0.25, 0.5, 1.0] {
        let xs: Vec<f64> = (0..x.len())
            .map(|k| {
                let pos = k as f64 + shift;
                let i = pos.floor().clamp(0.0, (x.len() - 2) as f64) as usize;
                let a = pos - i as f64;
                x[i] + a * (x[i + 1] - x[i])
            })
            .collect();
        let (_, aside) = rel_rms_noise_aside(&xs, rec, c.bench.laser.noise_m);
        eprintln!(
            "p1 main, sim shifted {shift} samples: {:.4} % RMS",
            aside * 100.0
        );
    }
    // Where the difference is: per second.
    let n = rec.len();
    for s in 0..(n / 48000) {
        let r = s * 48000..((s + 1) * 48000).min(n);
        let (_, aside) = rel_rms_noise_aside(&x[r.clone()], &rec[r], c.bench.laser.noise_m);
        eprintln!("p1 main, second {s}: {:.4} % RMS", aside * 100.0);
    }
}

/// Alternative formulations of the leaky adiabatic box, integrated by a
/// small stand-alone RK4 (same step), to explain the remaining difference on
/// p1's main sweep: 0 = pressure relaxation `p' = -gamma pabs V'/V - p/tau`
/// (the first version of the virtual bench), 1 = leak as a volume `q' = p CAB/tau`, `pabs = p0 (V0/(V+q))^gamma`,
/// 2 = air mass `M' = -rho p/RAL`, `pabs = p0 (M/M0 V0/V)^gamma` (the virtual bench now).
fn alt_box(c: &Case, drive: &[f64], variant: u32) -> Vec<f64> {
    let b = &c.bench;
    let e = &b.exciter;
    let (v0, g, p0, tau) = (
        b.box_.volume_m3,
        b.box_.gamma,
        b.box_.p0_pa,
        b.box_.leak_tau_s,
    );
    let cab = v0 / (g * p0);
    let part = &c.part;
    let k = |x: f64| part.k_coeffs_si.iter().rev().fold(0.0, |a, &ci| a * x + ci);
    // state: x, v, xd, vd, w (p for 0, q for 1, M/M0 for 2)
    let pressure = |s: &[f64; 5]| -> f64 {
        let vol = v0 - e.sd_m2 * s[2] + part.ss_m2 * s[0];
        match variant {
            0 => s[4],
            1 => p0 * (v0 / (vol + s[4])).powf(g) - p0,
            _ => p0 * (s[4] * v0 / vol).powf(g) - p0,
        }
    };
    let f = |s: &[f64; 5], u: f64| -> [f64; 5] {
        let p = pressure(s);
        let i = (u - e.bl_tm * s[3]) / e.re_ohm;
        let a = (part.ss_m2 * p - part.r_ns_per_m * s[1] - k(s[0]) * s[0]) / part.moving_mass_kg;
        let ad =
            (e.bl_tm * i - e.rmd_ns_per_m * s[3] - e.kmd_n_per_m * s[2] - e.sd_m2 * p) / e.mmd_kg;
        let vol = v0 - e.sd_m2 * s[2] + part.ss_m2 * s[0];
        let dvol = -e.sd_m2 * s[3] + part.ss_m2 * s[1];
        let dw = match variant {
            0 => -g * (p0 + p) * dvol / vol - p / tau,
            1 => p * cab / tau,
            _ => -(s[4] * v0 / vol) * p * cab / tau / v0,
        };
        [s[1], a, s[3], ad, dw]
    };
    let h = 1.0 / c.set.meta.sample_rate_hz;
    let mut s = [0.0, 0.0, 0.0, 0.0, if variant == 2 { 1.0 } else { 0.0 }];
    let mut xs = Vec::with_capacity(drive.len());
    for kk in 0..drive.len() {
        xs.push(s[0]);
        let u0 = drive[kk];
        let u1 = drive.get(kk + 1).copied().unwrap_or(0.0);
        let um = 0.5 * (u0 + u1);
        let add = |s: &[f64; 5], d: &[f64; 5], w: f64| {
            let mut o = *s;
            for j in 0..5 {
                o[j] += w * d[j];
            }
            o
        };
        let k1 = f(&s, u0);
        let k2 = f(&add(&s, &k1, 0.5 * h), um);
        let k3 = f(&add(&s, &k2, 0.5 * h), um);
        let k4 = f(&add(&s, &k3, h), u1);
        for j in 0..5 {
            s[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
        }
    }
    xs
}

#[test]
#[ignore = "investigation for the docs, prints figures"]
fn p1_main_difference_by_leak_formulation() {
    let c = load("p1_spider");
    let fs = c.set.meta.sample_rate_hz;
    for (name, spec, rec) in [("pre", c.pre, &c.set.pre), ("main", c.main, &c.set.main)] {
        let drive = spec.samples(fs);
        for (variant, what) in [
            (0, "pressure relaxation (first version)"),
            (1, "leak as volume"),
            (2, "air mass (the virtual bench)"),
        ] {
            let x = alt_box(&c, &drive, variant);
            let (_, aside) = rel_rms_noise_aside(&x, &rec.displacement_m, c.bench.laser.noise_m);
            eprintln!("p1 {name}, {what}: {:.4} % RMS", aside * 100.0);
        }
    }
}
