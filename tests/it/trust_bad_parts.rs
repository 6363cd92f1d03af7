//! Trust on bad parts (issue 22): on the virtual bench, parts a production
//! line meets — a drive limit far below the target, laser noise off a dark
//! surface, creep with its corner in the pre-measurement's band, a second
//! mechanical mode (outside the effect library), dry friction that sticks —
//! never get an unphysical headline value, and every headline value is
//! either within its stated accuracy of the part's truth or marked with a
//! state other than `valid` and a reason. Both documents are checked: the
//! plain analysis (a job's result) and the diagnosed one (`--diagnose`, a
//! fit), each with the Keff at an 8 mm target a daemon job adds.
//!
//! Stated accuracy of a `valid` value (docs/diagnostics.md, "Bad parts"):
//! K(x) 1 % RMS over the valid range, k0 3 %, f0 1.5 %, small-signal R and
//! Q 10 %, R of the main sweep 5 %, Keff (at the reached Xpeak and at the
//! target) 1.5 %.
//!
//! By default one seed of every class on spider_4in (the CI run), and the
//! two parts of the acceptance (creep on passive_radiator, a second
//! mode on spider_4in) over 3 seeds; `SPRINGBENCH_BAD_SEEDS=3 SPRINGBENCH_BAD_PRESETS=all` is
//! the whole suite (3 seeds per case, every preset) whose figures are in
//! docs/diagnostics.md.
use rand::{Rng, SeedableRng};
use springbench::bench::simulate::{simulate, SimulateOptions};
use springbench::diagnose::{diagnose, DiagnoseOptions};
use springbench::effects::{CoulombFriction, Creep};
use springbench::identify::large::describing_function_keff;
use springbench::identify::validity::{HeadlineValidity, State};
use springbench::identify::{analyze, AnalyzeOptions, Report};
use springbench::physics::{preset, preset_names, PartSpec, SecondMode};
use std::collections::HashMap;
use std::sync::{Mutex, OnceLock};

const TARGET_M: f64 = 0.008;

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn presets() -> Vec<String> {
    match std::env::var("SPRINGBENCH_BAD_PRESETS").ok().as_deref() {
        Some("all") => preset_names().iter().map(|s| s.to_string()).collect(),
        Some(list) if !list.is_empty() => list.split(',').map(|s| s.to_string()).collect(),
        _ => vec!["spider_4in".into()],
    }
}

/// The drive (V) that reaches the 8 mm target on the part (seed 0 of the
/// preset, default limits): a drive limit at a fraction of it keeps the
/// part near that fraction of the target.
fn target_drive_v(name: &str) -> f64 {
    static CACHE: OnceLock<Mutex<HashMap<String, f64>>> = OnceLock::new();
    let cache = CACHE.get_or_init(Default::default);
    if let Some(v) = cache.lock().unwrap().get(name) {
        return *v;
    }
    let part = preset(name).unwrap();
    let s = simulate(&part, 0, &SimulateOptions::default()).unwrap();
    let v = s.outcome.narrow[0].drive_v;
    cache.lock().unwrap().insert(name.into(), v);
    v
}

#[derive(Debug, Clone, Copy)]
enum Case {
    /// Drive limited to this fraction of the drive that reaches the target.
    DriveLimit(f64),
    /// Laser noise (m RMS).
    LaserNoise(f64),
    /// Creep of 12 % of k0 with this tau (s).
    Creep(f64),
    /// A second mode of 10 % of the moving mass at this frequency (Hz), Q 5.
    SecondMode(f64),
    /// Dry friction that sticks the part at the pre-measurement's level.
    Sticking,
}

impl Case {
    fn class(self) -> &'static str {
        match self {
            Case::DriveLimit(_) => "drive_limit",
            Case::LaserNoise(_) => "laser_noise",
            Case::Creep(_) => "creep",
            Case::SecondMode(_) => "second_mode",
            Case::Sticking => "sticking_friction",
        }
    }
}

/// The part and the simulation options of `case` on preset `name`.
fn setup(name: &str, case: Case) -> (PartSpec, SimulateOptions) {
    let mut part = preset(name).unwrap();
    let mut opts = SimulateOptions::default();
    let k0 = part.k_coeffs_si[0];
    match case {
        Case::DriveLimit(f) => {
            let mut l = springbench::bench::virtual_bench::DEFAULT_LIMITS;
            l.max_drive_v = f * target_drive_v(name);
            opts.limits = Some(l);
        }
        Case::LaserNoise(n) => part.laser_noise_m = Some(n),
        Case::Creep(tau) => {
            part.effects.creep = Some(Creep {
                k_n_per_m: 0.12 * k0,
                tau_s: tau,
            })
        }
        Case::SecondMode(f) => {
            part.second_mode = Some(SecondMode {
                mass_kg: 0.1 * part.moving_mass_kg,
                f_hz: f,
                q: 5.0,
            })
        }
        Case::Sticking => {
            // Twice the drive force at resonance of the pre-measurement's
            // 1 mm (k0 x / Q): the part sticks away from resonance there.
            let force = 2.0 * k0 * 1e-3 / part.q();
            part.effects.coulomb_friction = Some(CoulombFriction {
                force_n: force,
                v_eps_m_per_s: 1e-3,
            })
        }
    }
    (part, opts)
}

/// The cases of a class for seed `seed` (the varying size drawn per seed).
fn cases(seed: u64) -> Vec<Case> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2200 + seed);
    let mut out: Vec<Case> = [0.01, 0.1, 0.5].map(Case::DriveLimit).to_vec();
    out.extend([10e-6, 30e-6, 60e-6].map(Case::LaserNoise));
    // Creep's tau over the 5-50 ms: both ends (corner 32 Hz, above
    // cone_18in's resonance; 3.2 Hz, below the pre-measurement's 5 Hz
    // start) and one drawn between them.
    out.extend([0.005, 0.05].map(Case::Creep));
    out.push(Case::Creep(rng.random_range(0.005..0.05)));
    out.push(Case::SecondMode(rng.random_range(60.0..120.0)));
    out.push(Case::Sticking);
    out
}

/// One headline value against its truth.
#[derive(Debug, Clone)]
struct Check {
    name: &'static str,
    error_percent: f64,
    bound_percent: f64,
    state: State,
    reason: Option<String>,
}

fn k_of(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |a, k| a * x + k)
}

fn pct(a: f64, b: f64) -> f64 {
    100.0 * (a / b - 1.0)
}

/// Every headline value of `r` against `part`; panics on an unphysical one.
fn checks(part: &PartSpec, r: &Report, what: &str) -> Vec<Check> {
    let mut out = Vec::new();
    let mut push = |name, err: f64, bound, v: &HeadlineValidity| {
        out.push(Check {
            name,
            error_percent: err,
            bound_percent: bound,
            state: v.state,
            reason: v.reason.clone(),
        })
    };
    let k0 = part.k_coeffs_si[0];
    let m = part.moving_mass_kg;
    if let Some(s) = &r.small_signal {
        let v = &s.validity;
        for (n, x, st) in [
            ("k0", s.k0_n_per_m, &v.k0_n_per_m),
            ("f0", s.f0_hz, &v.f0_hz),
            ("small-signal R", s.r_ns_per_m, &v.r_ns_per_m),
            ("Q", s.q, &v.q),
        ] {
            match x {
                Some(x) => assert!(x > 0.0 && x.is_finite(), "{what}: {n} = {x} is a headline"),
                None => assert_eq!(st.state, State::NotDetermined, "{what}: {n} null"),
            }
            if st.state == State::NotDetermined {
                assert!(x.is_none(), "{what}: {n} not determined but shown: {x:?}");
                assert!(st.reason.is_some(), "{what}: {n} without a reason");
            }
        }
        if let Some(x) = s.k0_n_per_m {
            push("k0", pct(x, k0), 3.0, &v.k0_n_per_m);
        }
        if let Some(x) = s.f0_hz {
            push("f0", pct(x, part.f0_hz()), 1.5, &v.f0_hz);
        }
        if let Some(x) = s.r_ns_per_m {
            push(
                "small-signal R",
                pct(x, part.r_ns_per_m),
                10.0,
                &v.r_ns_per_m,
            );
        }
        if let Some(x) = s.q {
            push("Q", pct(x, part.q()), 10.0, &v.q);
        }
    }
    let st = &r.stiffness;
    let c = &st.coefficients_n_per_m_pow_i_plus_1;
    let [lo, hi] = st.valid_range_m;
    let (mut se, mut sq, mut kmin) = (0.0, 0.0, f64::INFINITY);
    for i in 0..=200 {
        let x = lo + (hi - lo) * i as f64 / 200.0;
        let kt = part.stiffness_n_per_m(x);
        let kf = k_of(c, x);
        kmin = kmin.min(kf);
        se += (kf - kt).powi(2);
        sq += kt * kt;
    }
    if st.validity.k_of_x.state != State::NotDetermined {
        assert!(
            kmin > 0.0,
            "{what}: K(x) reaches {kmin} N/m inside its range"
        );
    }
    push("K(x)", 100.0 * (se / sq).sqrt(), 1.0, &st.validity.k_of_x);
    if st.validity.r_ns_per_m.state != State::NotDetermined {
        assert!(st.r_ns_per_m > 0.0, "{what}: R = {}", st.r_ns_per_m);
    }
    push(
        "R",
        pct(st.r_ns_per_m, part.r_ns_per_m),
        5.0,
        &st.validity.r_ns_per_m,
    );
    let l = &r.large_signal;
    assert!(l.keff_n_per_m > 0.0 && l.keff_n_per_m.is_finite());
    let keff_true = describing_function_keff(
        &part.k_coeffs_si,
        l.x_min_at_resonance_m,
        l.x_max_at_resonance_m,
    );
    push(
        "Keff",
        pct(l.keff_n_per_m, keff_true),
        1.5,
        &l.validity.keff_n_per_m,
    );
    let _ = m;
    if let Some(xt) = l.target_xpeak_m {
        let v = l
            .validity
            .keff_at_target_n_per_m
            .clone()
            .expect("a state for Keff at the target");
        let cc = 0.5 * (l.x_min_at_resonance_m + l.x_max_at_resonance_m);
        let truth = describing_function_keff(&part.k_coeffs_si, cc - xt, cc + xt);
        match l.keff_at_target_n_per_m {
            Some(x) => {
                assert!(x > 0.0 && x.is_finite(), "{what}: Keff at target {x}");
                push("Keff at target", pct(x, truth), 1.5, &v);
            }
            None => {
                assert_eq!(v.state, State::NotDetermined);
                push("Keff at target", f64::NAN, 1.5, &v);
            }
        }
    }
    out
}

/// Runs one case and returns a line per document with every check; panics
/// when a valid value is out of its bound.
fn run_case(name: &str, case: Case, seed: u64) -> Vec<(String, Vec<Check>)> {
    let (part, opts) = setup(name, case);
    let sim = simulate(&part, 100 + seed, &opts).unwrap();
    let reached = sim.outcome.narrow[0].xpeak_m;
    let mut plain = analyze(&sim.set, &AnalyzeOptions::default()).unwrap();
    springbench::qc::set_keff_at_target(&mut plain, Some(TARGET_M));
    let mut diag = diagnose(&sim.set, &DiagnoseOptions::default())
        .unwrap()
        .report;
    springbench::qc::set_keff_at_target(&mut diag, Some(TARGET_M));
    let mut out = Vec::new();
    for (doc, r) in [("plain", &plain), ("diagnosed", &diag)] {
        let what = format!(
            "{name} {case:?} seed {seed} {doc} (Xpeak {:.3} mm)",
            reached * 1e3
        );
        let c = checks(&part, r, &what);
        // One write per document, so that the lines of parallel tests do not
        // interleave (the figures in docs/diagnostics.md are read from them).
        let mut text = format!(
            "{what}: model {:?} (model error {:.2} %, noise floor {:.2} %), small-signal {:?} (misfit {:.2} %, reliable {:?})\n",
            r.model.effects.ids(),
            r.model.model_error_percent,
            r.model.noise_floor_percent,
            r.small_signal.as_ref().map(|s| s.effects.ids()),
            r.small_signal.as_ref().map_or(f64::NAN, |s| s.misfit_percent),
            r.small_signal.as_ref().map(|s| s.reliable),
        );
        for k in &c {
            text.push_str(&format!(
                "    {:<15} {:>+9.3} % (bound {:>4}) {:<14} {}\n",
                k.name,
                k.error_percent,
                k.bound_percent,
                k.state.as_str(),
                k.reason.as_deref().unwrap_or("")
            ));
        }
        eprint!("{text}");
        out.push((what, c));
    }
    out
}

/// The valid values of `checks` outside their bound, one line each.
fn out_of_bound(what: &str, checks: &[Check]) -> Vec<String> {
    checks
        .iter()
        .filter(|k| k.state == State::Valid)
        .filter(|k| k.error_percent.is_nan() || k.error_percent.abs() > k.bound_percent)
        .map(|k| {
            format!(
                "{what}: {} valid but {:+.3} % off (bound {} %)",
                k.name, k.error_percent, k.bound_percent
            )
        })
        .collect()
}

/// Seeds of the two acceptance parts: 3 by default (the issue's
/// acceptance), `SPRINGBENCH_BAD_SEEDS` otherwise.
fn acceptance_seeds() -> u64 {
    env_usize("SPRINGBENCH_BAD_SEEDS", 3) as u64
}

/// Runs every case of `class` over the seeds and presets; fails with every
/// valid value outside its bound.
fn check_class(class: &str) {
    let seeds = env_usize("SPRINGBENCH_BAD_SEEDS", 1) as u64;
    let mut failures = Vec::new();
    let mut worst: HashMap<&'static str, (f64, String)> = HashMap::new();
    for name in presets() {
        for seed in 0..seeds {
            for case in cases(seed).into_iter().filter(|c| c.class() == class) {
                for (what, checks) in run_case(&name, case, seed) {
                    for k in checks.iter().filter(|k| k.state == State::Valid) {
                        let e = k.error_percent.abs();
                        let w = worst.entry(k.name).or_insert((0.0, String::new()));
                        if e > w.0 {
                            *w = (e, what.clone());
                        }
                    }
                    failures.extend(out_of_bound(&what, &checks));
                }
            }
        }
    }
    let mut w: Vec<_> = worst.into_iter().collect();
    w.sort_by(|a, b| a.0.cmp(b.0));
    for (n, (e, what)) in w {
        eprintln!("{class}: worst valid {n}: {e:.3} % ({what})");
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn drive_limit() {
    check_class("drive_limit");
}

#[test]
fn laser_noise() {
    check_class("laser_noise");
}

#[test]
fn creep_in_the_pre_measurement_band() {
    check_class("creep");
}

#[test]
fn second_mode() {
    check_class("second_mode");
}

#[test]
fn sticking_friction() {
    check_class("sticking_friction");
}

/// The plain analysis (a job's result) of creep on the two strongly
/// hardening spiders, the cases of the suite that were `valid` and wrong
/// (spider_4in tau 28.6 ms: k0 +13 %, K(x) 9 % RMS, Keff +7 %; spider_3in
/// tau 20.8 ms): their spider's harmonics fill the whole band's misfit, so
/// creep is judged below the resonance (decision 0052). Plain analysis
/// only: seconds.
#[test]
fn creep_on_hardening_spiders_in_the_plain_analysis() {
    let mut failures = Vec::new();
    // The suite's draws before it covered 5-50 ms (tau 28.6 and 20.8 ms).
    for (name, seed, tau) in [("spider_4in", 1, 0.0286), ("spider_3in", 2, 0.0208)] {
        let (plain, c, what) = plain_checks(name, Case::Creep(tau), seed);
        failures.extend(out_of_bound(&what, &c));
        // The reason names the experiment that would tell.
        let v = &plain.small_signal.as_ref().unwrap().validity.k0_n_per_m;
        if !v.is_valid() {
            let why = v.reason.as_deref().unwrap_or("");
            assert!(why.contains("would separate"), "{why}");
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The plain analysis (a job's result, Keff at the 8 mm target) of `case`
/// on preset `name`, its checks printed one line each.
fn plain_checks(name: &str, case: Case, seed: u64) -> (Report, Vec<Check>, String) {
    let (part, opts) = setup(name, case);
    let sim = simulate(&part, 100 + seed, &opts).unwrap();
    let mut plain = analyze(&sim.set, &AnalyzeOptions::default()).unwrap();
    springbench::qc::set_keff_at_target(&mut plain, Some(TARGET_M));
    let what = format!("{name} {case:?} seed {seed} plain");
    let c = checks(&part, &plain, &what);
    for k in &c {
        eprintln!(
            "{what}: {:<15} {:>+9.3} % {:<14} {}",
            k.name,
            k.error_percent,
            k.state.as_str(),
            k.reason.as_deref().unwrap_or("")
        );
    }
    (plain, c, what)
}

/// The plain analysis of creep at the ends of the tau range on
/// cone_18in (f0 14 Hz: no band below its resonance an octave wide), which
/// left every value `valid` and wrong before the whole band's held-out
/// creep check: tau 50 ms (corner 3.2 Hz, below the pre-measurement's
/// 5 Hz start) k0 +11.4 %, K(x) 10.7 % RMS, Keff +10.7 %; tau 5 ms (corner
/// 32 Hz, above the resonance) small-signal R +19 %, R +19 %, K(x) 1.8 %.
/// Plain analysis only: seconds.
#[test]
fn creep_at_the_ends_of_the_tau_range_on_cone_18in() {
    let mut failures = Vec::new();
    for tau in [0.005, 0.05] {
        let (_, c, what) = plain_checks("cone_18in", Case::Creep(tau), 0);
        failures.extend(out_of_bound(&what, &c));
        // A marked k0 or K(x) names the experiment that would tell.
        for k in c
            .iter()
            .filter(|k| k.state != State::Valid && (k.name == "k0" || k.name == "K(x)"))
        {
            let why = k.reason.as_deref().unwrap_or("");
            assert!(why.contains("would separate"), "{what}: {}: {why}", k.name);
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The diagnosed documents of creep at the ends of the tau range on
/// passive_radiator (f0 16 Hz), which were `valid` outside their accuracy
/// (decision 0072): tau 5 ms (creep a damping at the resonance: it trades
/// against R) small-signal R -14.6 %, Q +16.9 %; tau 50 ms (corner 3.2 Hz,
/// below the band: creep a constant stiffness, it trades against K(x))
/// K(x) 2.3 % RMS, Keff -2.0 %. With creep's tau free their uncertainty
/// exceeds their accuracy: marked, with the experiment that would tell.
/// Diagnosed only, one seed: seconds.
#[test]
fn creep_at_the_ends_of_the_tau_range_on_the_passive_radiator_diagnosed() {
    let mut failures = Vec::new();
    for tau in [0.005, 0.05] {
        let (part, opts) = setup("passive_radiator", Case::Creep(tau));
        let sim = simulate(&part, 100, &opts).unwrap();
        let mut d = diagnose(&sim.set, &DiagnoseOptions::default())
            .unwrap()
            .report;
        springbench::qc::set_keff_at_target(&mut d, Some(TARGET_M));
        let what = format!("passive_radiator creep tau {tau} s seed 100 diagnosed");
        let c = checks(&part, &d, &what);
        failures.extend(out_of_bound(&what, &c));
        for k in c.iter().filter(|k| k.state != State::Valid) {
            let why = k.reason.as_deref().unwrap_or("");
            eprintln!(
                "{what}: {} {:+.2} % {}: {why}",
                k.name,
                k.error_percent,
                k.state.as_str()
            );
            // (Keff and Keff at the target give K(x)'s state as theirs.)
            if !k.name.starts_with("Keff") {
                assert!(why.contains("would separate"), "{what}: {}: {why}", k.name);
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The figures of the creep check below the resonance (decision 0052) on
/// good parts and on every bad-part class, for every preset:
/// `SPRINGBENCH_BAD_SEEDS=3 cargo test --test it trust_bad_parts:: -- --ignored
/// --nocapture below_resonance_creep_figures`.
#[test]
#[ignore]
fn below_resonance_creep_figures() {
    let all: Vec<String> = preset_names().iter().map(|s| s.to_string()).collect();
    small_fits_of_every_part(&all, |what, part, f| {
        let k0 = part.k_coeffs_si[0];
        let k0_fit = f.result.k0_n_per_m.unwrap_or(f64::NAN);
        match &f.below_resonance {
                    Some(b) => eprintln!(
                        "BELOW {what}: band {:.1}-{:.1} Hz misfit {:.2} -> {:.2} % noise {:.2} % share {:.0} % tau {:.1} ms kc {:.0} N/m; k0 {:+.2} %, static k0 with creep {:+.2} % (change {:+.2} %); marked {}",
                        b.band_hz[0],
                        b.band_hz[1],
                        b.misfit_linear_percent,
                        b.misfit_with_creep_percent,
                        b.noise_misfit_percent,
                        b.creep_share_percent(),
                        b.creep_tau_s * 1e3,
                        b.creep_k_n_per_m,
                        pct(k0_fit, k0),
                        pct(b.creep_k0_n_per_m, k0),
                        pct(b.creep_k0_n_per_m, k0_fit),
                        f.creep.is_some()
                    ),
                    None => eprintln!(
                        "BELOW {what}: no band; k0 {:+.2} %; marked {}",
                        pct(k0_fit, k0),
                        f.creep.is_some()
                    ),
                }
    });
}

/// Runs the small-signal fit (the plain analysis's) of every part, good and
/// of every bad-part class, on `presets` over `SPRINGBENCH_BAD_SEEDS` seeds
/// (3 unless set) and hands each to `f` with its name.
fn small_fits_of_every_part(
    presets: &[String],
    mut f: impl FnMut(&str, &PartSpec, &springbench::identify::SmallFit),
) {
    let seeds = env_usize("SPRINGBENCH_BAD_SEEDS", 3) as u64;
    for name in presets {
        for seed in 0..seeds {
            let mut all: Vec<Option<Case>> = vec![None];
            all.extend(cases(seed).into_iter().map(Some));
            for case in all {
                let (part, opts) = match case {
                    Some(c) => setup(name, c),
                    None => (preset(name).unwrap(), SimulateOptions::default()),
                };
                let sim = simulate(&part, 100 + seed, &opts).unwrap();
                let fit = springbench::identify::small_signal_fit(
                    &sim.set.pre,
                    sim.set.meta.moving_mass_kg,
                )
                .unwrap();
                f(&format!("{name} {case:?} seed {seed}"), &part, &fit);
            }
        }
    }
}

/// The figures of the whole band's creep check (decisions 0062, 0073) on good parts and on every
/// bad-part class, for every preset, plain analysis:
/// `SPRINGBENCH_BAD_SEEDS=3 cargo test --test it trust_bad_parts:: -- --ignored
/// --nocapture whole_band_creep_figures`.
#[test]
#[ignore]
fn whole_band_creep_figures() {
    small_fits_of_every_part(&presets_or_all(), |what, part, f| {
        let s = &f.result;
        let (Some(k0), Some(r)) = (s.k0_n_per_m, s.r_ns_per_m) else {
            return;
        };
        let Some(w) = &f.whole_band else {
            eprintln!("WHOLE {what}: no band");
            return;
        };
        eprintln!(
                    "WHOLE {what}: misfit {:.2} -> {:.2} %, {} of 5 blocks (held-out gain z {:.1}), tau {:.1} ms, kc {:.0} N/m; static k0 {:+.2} % (se {:.2} %), R {:+.2} % (se {:.2} %) of the headline's (of the band's linear resonator: {:+.2} %, {:+.2} %); headline k0 {:+.2} %, R {:+.2} % of the part's; marked {}",
                    w.misfit_linear_percent,
                    w.misfit_with_creep_percent,
                    w.creep_folds_won,
                    w.creep_held_out_gain_z,
                    w.creep_tau_s * 1e3,
                    w.creep_k_n_per_m,
                    pct(w.creep_k0_n_per_m, k0),
                    100.0 * w.creep_k0_se_n_per_m / k0,
                    pct(w.creep_r_ns_per_m, r),
                    100.0 * w.creep_r_se_ns_per_m / r,
                    pct(w.creep_k0_n_per_m, w.k0_linear_n_per_m),
                    pct(w.creep_r_ns_per_m, w.r_linear_ns_per_m),
                    pct(k0, part.k_coeffs_si[0]),
                    pct(r, part.r_ns_per_m),
                    f.creep.is_some()
                );
    });
}

/// The presets of `SPRINGBENCH_BAD_PRESETS`, every preset when unset.
fn presets_or_all() -> Vec<String> {
    match std::env::var("SPRINGBENCH_BAD_PRESETS") {
        Ok(_) => presets(),
        Err(_) => preset_names().iter().map(|s| s.to_string()).collect(),
    }
}

/// Acceptance: creep on passive_radiator (tau 20 ms, 12 % of k0; corner
/// 8 Hz, inside the pre-measurement's 5-100 Hz): the headline small-signal
/// k0 is within 3 % of the part's k0, or marked with the reason and the
/// experiment that would tell.
#[test]
fn creep_on_the_passive_radiator() {
    let mut part = preset("passive_radiator").unwrap();
    let k0 = part.k_coeffs_si[0];
    part.effects.creep = Some(Creep {
        k_n_per_m: 0.12 * k0,
        tau_s: 0.02,
    });
    for seed in 0..acceptance_seeds() {
        let sim = simulate(&part, 300 + seed, &SimulateOptions::default()).unwrap();
        let mut d = diagnose(&sim.set, &DiagnoseOptions::default())
            .unwrap()
            .report;
        let ss = d.small_signal.as_ref().unwrap();
        let v = &ss.validity.k0_n_per_m;
        let err = ss.k0_n_per_m.map(|x| pct(x, k0));
        eprintln!(
            "passive_radiator creep seed {seed}: k0 {err:?} % ({:?}), small-signal effects {:?} {:?}, main {:?}",
            v,
            ss.effects.ids(),
            ss.effects.creep,
            d.model.effects.creep
        );
        match err {
            Some(e) if v.is_valid() => assert!(e.abs() <= 3.0, "k0 {e} % valid"),
            _ => {
                let why = v.reason.as_deref().unwrap_or("");
                assert!(!v.is_valid() && !why.is_empty(), "{v:?}");
            }
        }
        // The creep of the part is found in both models, near its size.
        let c = ss.effects.creep.expect("creep in the small-signal model");
        assert!((c.k_n_per_m / (0.12 * k0) - 1.0).abs() < 0.25, "{c:?}");
        // The plain analysis of the same recording marks its (creep-biased)
        // linear resonator.
        let mut plain = analyze(&sim.set, &AnalyzeOptions::default()).unwrap();
        let ps = plain.small_signal.clone().unwrap();
        let pe = pct(ps.k0_n_per_m.unwrap(), k0);
        eprintln!("  plain k0 {pe:+.2} % {:?}", ps.validity.k0_n_per_m);
        assert!(pe.abs() <= 3.0 || !ps.validity.k0_n_per_m.is_valid());
        // Every headline value of both documents (with Keff at an 8 mm
        // target, as a job's) is within its stated accuracy or marked: the
        // plain analysis's K(x), R and Keff are biased by the creep it
        // cannot hold (K(x) +9 %, R +27 % before they were marked).
        for (doc, r) in [("plain", &mut plain), ("diagnosed", &mut d)] {
            springbench::qc::set_keff_at_target(r, Some(TARGET_M));
            let what = format!("passive_radiator creep seed {seed} {doc}");
            let bad = out_of_bound(&what, &checks(&part, r, &what));
            assert!(bad.is_empty(), "{bad:#?}");
        }
    }
}

/// Acceptance: a second mode on spider_4in (6 g of its 50 g on its own
/// spring at 75 Hz, Q 5, the part the issue describes): no library effect
/// enters the headline model, the report names a resonance within 10 % of
/// the mode's frequency and the falling sweep as the experiment that would
/// tell, and the headline values are marked.
#[test]
fn second_mode_on_the_spider_is_named() {
    let mut part = preset("spider_4in").unwrap();
    let f2 = 75.0;
    part.second_mode = Some(SecondMode {
        mass_kg: 0.006,
        f_hz: f2,
        q: 5.0,
    });
    for seed in 0..acceptance_seeds() {
        let sim = simulate(&part, 400 + seed, &SimulateOptions::default()).unwrap();
        let r = diagnose(&sim.set, &DiagnoseOptions::default())
            .unwrap()
            .report;
        let u = serde_json::to_value(&r.diagnostics).unwrap()["unexplained"].clone();
        eprintln!(
            "second mode seed {seed}: headline {:?}, small-signal {:?}, ladder {}, resonance {}, experiments {}",
            r.model.effects.ids(),
            r.small_signal.as_ref().map(|s| s.effects.ids()),
            serde_json::to_value(&r.diagnostics).unwrap()["ladder"],
            u["resonance"],
            u["experiments"]
        );
        assert!(r.model.effects.is_empty(), "{:?}", r.model.effects);
        assert!(r.small_signal.as_ref().unwrap().effects.is_empty());
        let f = u["resonance"]["frequency_hz"]
            .as_f64()
            .expect("a resonance");
        assert!((f / f2 - 1.0).abs() <= 0.1, "{f} Hz");
        assert!(u["experiments"][0]
            .as_str()
            .unwrap()
            .starts_with("a falling sweep"));
        assert!(r.warnings.iter().any(|w| w.contains("falling sweep")));
        assert_eq!(r.stiffness.validity.k_of_x.state, State::Unreliable);
        let why = r.stiffness.validity.k_of_x.reason.as_deref().unwrap();
        assert!(why.contains("resonance at"), "{why}");
    }
}

/// A strongly hardening spider (spider_3in) on a good day: its
/// pre-measurement at 1.5 mm already bends K(x) by about 3 %, so the linear
/// resonator's k0 (+3.3 % of K(0) before) is either within k0's stated 3 %
/// or marked with the bend as its reason, in both documents.
#[test]
fn hardening_spider_small_signal_k0_at_its_level() {
    let part = preset("spider_3in").unwrap();
    let sim = simulate(&part, 500, &SimulateOptions::default()).unwrap();
    let plain = analyze(&sim.set, &AnalyzeOptions::default()).unwrap();
    let diag = diagnose(&sim.set, &DiagnoseOptions::default())
        .unwrap()
        .report;
    for (doc, r) in [("plain", &plain), ("diagnosed", &diag)] {
        let what = format!("spider_3in seed 500 {doc}");
        let c = checks(&part, r, &what);
        for k in c.iter().filter(|k| k.name == "k0") {
            eprintln!(
                "{what}: k0 {:+.3} % {} {:?}",
                k.error_percent,
                k.state.as_str(),
                k.reason
            );
        }
        let bad = out_of_bound(&what, &c);
        assert!(bad.is_empty(), "{bad:#?}");
    }
    let v = &plain.small_signal.as_ref().unwrap().validity.k0_n_per_m;
    if !v.is_valid() {
        assert!(v.reason.as_deref().unwrap().contains("bends K(x)"), "{v:?}");
    }
}
