//! Issue 21 acceptance: the production procedure against the full one on the
//! same parts of production lots, on the virtual bench.
//!
//! Per preset: 5 golden units measured with the full procedure give the
//! recipe's limits (mean +- 6 sigma) and the golden reference stored with
//! them (`qc::limits::propose`: resonances, Q, drive levels); then every lot
//! part is measured with both procedures, each on a fresh virtual bench of
//! the same part and seed, analysed and judged as the runner does (analysis,
//! Keff at the target, `qc::judge`).
//!
//! Run time: the lots run on two threads (CI has 2 cores). The spider_4in
//! lot of the issue (30 parts) and a 12-part lot of each other preset run by
//! default (about a minute of CPU per preset in the test profile);
//! `SPRINGBENCH_PRODUCTION_FULL=1` (set by `.ci/run`) runs 30 parts of every
//! preset. Nothing here asserts a wall time: bench time is the duration of
//! the stimulus the procedure played and captured (sweeps and their
//! silences), the time a real bench is busy with the part.

use springbench::bench::procedure::{self, Observer, Outcome, ProcedureConfig};
use springbench::bench::virtual_bench::{VirtualBench, DEFAULT_LIMITS};
use springbench::bench::Limits;
use springbench::identify::{self, AnalyzeOptions, Method};
use springbench::physics::production::{part, Defect, Spread};
use springbench::physics::{preset, PartSpec};
use springbench::qc::limits::{propose, GoldenUnit, ProposalOptions, Spread as LimitSpread};
use springbench::qc::{self, GoldenReference, Recipe, RunFacts, Verdict, VerdictKind};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Quiet;
impl Observer for Quiet {}

/// A preset's production line: its target level and the recipe's validity bounds.
struct Line {
    preset: &'static str,
    level_m: f64,
    /// The recipe's validity as JSON (the part type's bounds).
    validity: serde_json::Value,
}

fn lines() -> Vec<Line> {
    let default = serde_json::json!({});
    vec![
        Line {
            preset: "spider_4in",
            level_m: 0.008,
            validity: default.clone(),
        },
        Line {
            preset: "spider_3in",
            level_m: 0.008,
            validity: default.clone(),
        },
        Line {
            preset: "passive_radiator",
            level_m: 0.008,
            validity: default.clone(),
        },
        // The 6.5" cone jumps off the upper branch at about 7.4 mm of 8.
        Line {
            preset: "cone_6in",
            level_m: 0.006,
            validity: default,
        },
        // The 18" cone moves the box's air: the force balance's noise floor
        // is 8-12 % of its force (the full procedure's own golden units), and
        // its level control stops at 88 % of the target.
        Line {
            preset: "cone_18in",
            level_m: 0.006,
            validity: serde_json::json!({"max_noise_floor_percent": 15.0, "min_xpeak_ratio": 0.8}),
        },
    ]
}

/// The judged quantities (issue 21: k0, f0, Q, R, Keff at target, K at x, asymmetry, model error).
fn recipe(l: &Line) -> Recipe {
    let x = |f: f64| (l.level_m * f * 1e6).round() / 1e6;
    serde_json::from_value(serde_json::json!({
        "name": l.preset,
        "procedure": {"levels_m": [l.level_m], "method": "two-signal", "order": 4, "mode": "production"},
        "parameters": [
            {"name": "k0", "quantity": "k0"},
            {"name": "f0", "quantity": "f0"},
            {"name": "q", "quantity": "q"},
            {"name": "r", "quantity": "r"},
            {"name": "keff", "quantity": "keff"},
            {"name": "k_at_half", "quantity": "k_at_x", "x_m": x(0.5)},
            {"name": "asym_half", "quantity": "k_asymmetry", "x_m": x(0.5)},
            {"name": "model_error", "quantity": "model_error", "upper": 5.0}
        ],
        "validity": l.validity,
    }))
    .unwrap()
}

/// One measurement as the runner makes it.
struct Measured {
    outcome: Outcome,
    facts: RunFacts,
}

fn measure(
    p: &PartSpec,
    seed: u64,
    limits: Limits,
    level_m: f64,
    production: Option<Option<&GoldenReference>>,
) -> Measured {
    let mut vb = VirtualBench::new(p.clone(), seed).with_limits(limits);
    let cfg = ProcedureConfig {
        moving_mass_kg: p.moving_mass_kg,
        levels_m: vec![level_m],
        ..ProcedureConfig::default()
    };
    let outcome: Outcome = match production {
        None => procedure::run(&mut vb, &cfg, &mut Quiet),
        Some(g) => procedure::run_production(&mut vb, &cfg, g, &mut Quiet),
    }
    .unwrap();
    let sweep = &outcome.narrow[0];
    let mut meta =
        springbench::recording::Meta::standard(p.moving_mass_kg, outcome.pre.sample_rate_hz);
    meta.channels.drive = Some(2);
    let set = springbench::recording::RecordingSet {
        meta,
        pre: outcome.pre.clone(),
        main: sweep.signals.clone(),
    };
    let opts = AnalyzeOptions {
        method: Method::TwoSignal,
        order: Some(4),
    };
    let analysed = identify::analyze(&set, &opts).map(|mut r| {
        r.warnings.extend(sweep.warning.iter().cloned());
        qc::set_keff_at_target(&mut r, Some(level_m));
        r
    });
    let facts = RunFacts {
        report: analysed.as_ref().ok().cloned(),
        analysis_error: analysed.as_ref().err().map(|e| e.to_string()),
        target_xpeak_m: Some(level_m),
        level_index: 0,
        drive_v: Some(sweep.drive_v),
        max_drive_v: Some(limits.max_drive_v),
        pre_drive_v: Some(outcome.pre_sweep.amplitude_v),
        pre_q_drive_to_x: outcome.pre_q_drive_to_x,
    };
    Measured { outcome, facts }
}

/// `f` over `items` on two threads, results in order.
fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let next = AtomicUsize::new(0);
    let mut out: Vec<(usize, R)> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..2)
            .map(|_| {
                s.spawn(|| {
                    let mut mine = vec![];
                    loop {
                        let i = next.fetch_add(1, Ordering::SeqCst);
                        if i >= items.len() {
                            break mine;
                        }
                        mine.push((i, f(&items[i])));
                    }
                })
            })
            .collect();
        hs.into_iter().flat_map(|h| h.join().unwrap()).collect()
    });
    out.sort_by_key(|(i, _)| *i);
    out.into_iter().map(|(_, r)| r).collect()
}

/// The recipe with limits and golden reference from 5 golden units.
fn approved_recipe(l: &Line) -> Recipe {
    let nominal = preset(l.preset).unwrap();
    let rec = recipe(l);
    let seeds: Vec<u64> = (100..105).collect();
    let golden: Vec<GoldenUnit> = par_map(&seeds, |&s| {
        let p = part(&nominal, &Spread::default(), s, None);
        GoldenUnit {
            serial: format!("G-{s}"),
            measurements: vec![measure(&p, s, DEFAULT_LIMITS, l.level_m, None).facts],
        }
    });
    let opts = ProposalOptions {
        spread: LimitSpread::KSigma { k: 6.0 },
        mask_points: 0,
        mask_range_fraction: 0.9,
    };
    let rec = propose(&rec, &golden, &opts).unwrap().recipe;
    assert!(
        rec.procedure.golden.is_some(),
        "{}: no golden reference",
        l.preset
    );
    rec
}

/// A lot part: serial, the part, its seed, the bench's limits.
struct LotPart {
    serial: String,
    part: PartSpec,
    seed: u64,
    limits: Limits,
    unmeasurable: bool,
}

fn lot(nominal: &PartSpec, n_good: usize, defects: &[Defect]) -> Vec<LotPart> {
    let s = Spread::default();
    let mut v: Vec<LotPart> = (0..n_good as u64)
        .map(|i| LotPart {
            serial: format!("P-{i:02}"),
            part: part(nominal, &s, 500 + i, None),
            seed: 500 + i,
            limits: DEFAULT_LIMITS,
            unmeasurable: false,
        })
        .collect();
    for (i, d) in defects.iter().enumerate() {
        let seed = 700 + i as u64;
        v.push(LotPart {
            serial: format!("D-{d:?}"),
            part: part(nominal, &s, seed, Some(*d)),
            seed,
            limits: DEFAULT_LIMITS,
            unmeasurable: false,
        });
    }
    // Unmeasurable: an amplifier limited to 0.3 V cannot reach the target; a dark surface makes the laser noisy.
    v.push(LotPart {
        serial: "U-drive".into(),
        part: part(nominal, &s, 801, None),
        seed: 801,
        limits: Limits {
            max_drive_v: 0.3,
            ..DEFAULT_LIMITS
        },
        unmeasurable: true,
    });
    v.push(LotPart {
        serial: "U-dark".into(),
        part: part(nominal, &s, 802, Some(Defect::DarkSurface)),
        seed: 802,
        limits: DEFAULT_LIMITS,
        unmeasurable: true,
    });
    v
}

/// Value of a judged parameter.
fn value(v: &Verdict, name: &str) -> Option<f64> {
    v.parameters
        .iter()
        .find(|p| p.name == name)
        .map(|p| p.value)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Runs one preset's lot with both procedures and checks the acceptance.
fn acceptance(l: &Line, n_good: usize, defects: &[Defect]) {
    let rec = approved_recipe(l);
    let g = rec.procedure.golden.clone().unwrap();
    let nominal = preset(l.preset).unwrap();
    let parts = lot(&nominal, n_good, defects);
    let results: Vec<(Measured, Measured)> = par_map(&parts, |p| {
        (
            measure(&p.part, p.seed, p.limits, l.level_m, None),
            measure(&p.part, p.seed, p.limits, l.level_m, Some(Some(&g))),
        )
    });
    let mut wrong = vec![];
    let mut times = vec![];
    let mut worst: Vec<(String, f64)> = vec![];
    let equiv = ["k0", "keff", "k_at_half"];
    for (p, (full, prod)) in parts.iter().zip(&results) {
        let vf = qc::judge(&rec, &full.facts);
        let vp = qc::judge(&rec, &prod.facts);
        let run = prod.outcome.production.as_ref().expect("a production run");
        if vf.verdict != vp.verdict {
            wrong.push(format!(
                "{}: verdict full {:?} production {:?} ({:?} / {:?}; {:?})",
                p.serial,
                vf.verdict,
                vp.verdict,
                vf.invalid_reasons,
                vp.invalid_reasons,
                prod.outcome.log
            ));
        }
        if p.unmeasurable && vp.verdict == VerdictKind::Pass {
            wrong.push(format!("{}: unmeasurable part passed", p.serial));
        }
        if run.fallback.is_none() {
            times.push(prod.outcome.bench_time_s);
            if vf.verdict != VerdictKind::Invalid && vp.verdict != VerdictKind::Invalid {
                for n in equiv {
                    let (a, b) = (value(&vf, n).unwrap(), value(&vp, n).unwrap());
                    let rel = 100.0 * (b / a - 1.0);
                    match worst.iter_mut().find(|w| w.0 == n) {
                        Some(w) => w.1 = w.1.max(rel.abs()),
                        None => worst.push((n.to_string(), rel.abs())),
                    }
                    if rel.abs() > 1.0 {
                        wrong.push(format!(
                            "{}: {n} full {a} production {b} ({rel:+.2} %)",
                            p.serial
                        ));
                    }
                }
            }
        }
    }
    let fallbacks: Vec<String> = parts
        .iter()
        .zip(&results)
        .filter_map(|(p, (_, m))| {
            let f = m.outcome.production.as_ref()?.fallback.as_ref()?;
            Some(format!("{}: {f}", p.serial))
        })
        .collect();
    let (med, max) = (
        median(times.clone()),
        times.iter().cloned().fold(0.0, f64::max),
    );
    eprintln!(
        "{}: {} parts, {} measured by the short procedure: bench time median {med:.2} s, max {max:.2} s \
         (full procedure median {:.1} s); largest deviation from the full procedure (%): {worst:?}; fall-backs: {fallbacks:?}",
        l.preset,
        parts.len(),
        times.len(),
        median(results.iter().map(|r| r.0.outcome.bench_time_s).collect()),
    );
    assert!(wrong.is_empty(), "{}:\n{}", l.preset, wrong.join("\n"));
    assert!(
        times.len() >= n_good,
        "{}: good parts fell back: {fallbacks:?}",
        l.preset
    );
    assert!(med <= 5.0, "{}: median bench time {med} s", l.preset);
    assert!(max <= 8.0, "{}: largest bench time {max} s", l.preset);
}

fn full_lots() -> bool {
    std::env::var("SPRINGBENCH_PRODUCTION_FULL").is_ok_and(|v| v == "1")
}

const DEFECTS: [Defect; 5] = [
    Defect::Stiff,
    Defect::Asymmetric,
    Defect::Hardening,
    Defect::Damped,
    Defect::Soft,
];

/// The issue's lot: 30 spider_4in parts (23 good, 5 defective, 2 unmeasurable).
#[test]
fn spider_4in_lot_agrees_with_the_full_procedure_in_a_5_s_cycle() {
    acceptance(&lines()[0], 23, &DEFECTS);
}

/// Every other preset with its own golden units (12 parts; 30 with SPRINGBENCH_PRODUCTION_FULL=1).
#[test]
fn every_other_preset_agrees_with_its_own_golden_units() {
    for l in &lines()[1..] {
        if full_lots() {
            acceptance(l, 23, &DEFECTS);
        } else {
            acceptance(l, 7, &DEFECTS[..3]);
        }
    }
}

/// A part 25 % stiffer than nominal falls back to the full search and says so.
#[test]
fn a_part_25_percent_stiffer_falls_back_and_says_so() {
    let l = &lines()[0];
    let rec = approved_recipe(l);
    let g = rec.procedure.golden.clone().unwrap();
    let mut p = part(&preset(l.preset).unwrap(), &Spread::default(), 900, None);
    p.k_coeffs_si.iter_mut().for_each(|k| *k *= 1.25);
    let m = measure(&p, 900, DEFAULT_LIMITS, l.level_m, Some(Some(&g)));
    let why = m
        .outcome
        .production
        .as_ref()
        .and_then(|r| r.fallback.clone())
        .expect("a 25 % stiffer part falls back");
    // sqrt(1.25) = +11.8 % in f0, beyond the 5 % the golden reference allows
    assert!(why.contains("small-signal f0"), "{why}");
    assert!(
        m.outcome
            .log
            .iter()
            .any(|l| l.starts_with("falls back to the full procedure")),
        "{:?}",
        m.outcome.log
    );
    // ... and the full procedure measured it: a resonance search ran.
    assert!(
        m.outcome.log.iter().any(|l| l.starts_with("search 0")),
        "{:?}",
        m.outcome.log
    );
    let full = measure(&p, 900, DEFAULT_LIMITS, l.level_m, None);
    let (vf, vp) = (qc::judge(&rec, &full.facts), qc::judge(&rec, &m.facts));
    assert_eq!(vf.verdict, vp.verdict);
    assert_eq!(vp.verdict, VerdictKind::Fail, "{vp:?}");
    // Without golden units the production procedure is the full one and says why.
    let m = measure(&p, 900, DEFAULT_LIMITS, l.level_m, Some(None));
    assert!(m
        .outcome
        .production
        .and_then(|r| r.fallback)
        .is_some_and(|w| w.contains("no golden reference")));
}
