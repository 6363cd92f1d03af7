//! The production procedure: what golden units established replaces the level
//! probe, the long pre-measurement and the resonance search.
//!
//! 1. A short pre-measurement (log sweep over f0/2^1.5 .. f0 2^1.5 of the
//!    golden f0 in [`PRE_S`]) at the golden pre-measurement drive, level
//!    checked like the full procedure's (redone once when the resonance
//!    amplitude is off by more than 2x). Its small-signal fit gives the
//!    part's f0; a part further than `max_f0_deviation_percent` from the
//!    golden f0 falls back to the full procedure.
//! 2. Per level one rising sweep through the golden large-signal resonance
//!    (scaled by the part's f0 / golden f0) at the golden drive aimed at the
//!    target (times the target over the golden units' Xpeak), over the
//!    full procedure's narrow band, paced by the ringing: it crosses the
//!    half-power bandwidth f/Q in [`N_TAU`] decay times tau = Q / (pi f)
//!    (production-notes: 3-5 tau). The level is checked inside the sweep: a
//!    large-signal resonance outside the sweep's band (the upper branch was
//!    not ridden from at least 1/3 octave below, or not crossed) falls
//!    back; an Xpeak (the analysis's: the excursion in the period at the
//!    resonance) more than the full procedure's search tolerance off the
//!    target gives one corrected sweep, and falls back when that one misses
//!    too.
//!
//! The safety rules are the full procedure's (`Ctx::play`): every block is
//! checked against the displacement limit and ramps the drive down; a sweep
//! that hit it is redone lower; the drive never exceeds the bench's limit.

use super::run::{
    aim_m, analyse, validate, Ctx, Stop, NARROW_ABOVE_OCT, NARROW_BELOW_OCT, SEARCH_TOL,
    SHORT_SILENCE_S,
};
use super::sweep::SweepSpec;
use super::{Observer, Outcome, ProcedureConfig, ProcedureError, ProductionRun, Step};
use crate::Bench;
use springbench_core::identify::validity::TARGET_MARGIN;
use springbench_core::qc::GoldenReference;

/// Length of the short pre-measurement sweep (s): its three octaves put
/// about 1.2 f0 s of FFT bins into the small-signal fit's band f0/2 .. 2 f0
/// (17 bins at the 13.8 Hz of the 18-inch cone; the fit needs 20 and pads).
pub const PRE_S: f64 = 1.5;
/// Octaves of the short pre-measurement on each side of the golden f0.
const PRE_OCT: f64 = 1.5;
/// Decay times tau = Q / (pi f) the narrow sweep takes to cross the
/// half-power bandwidth f / Q (production-notes: 3-5; the lower end keeps
/// the passive radiator's 20 Hz, Q 10 within the 5 s cycle).
pub const N_TAU: f64 = 3.0;
/// Shortest narrow sweep (s). Its fades take 0.5 s; measured on a
/// spider_4in part (`explore_grr` in tests/production.rs, decision 0059),
/// the sd of Keff at target and K(4 mm) from a 1 s sweep is 1.8-2.6x the
/// 10 s sweep's, from a 2 s sweep in the same band within the estimate's
/// own spread of it (laser noise is all of it).
const MIN_NARROW_S: f64 = 2.0;
/// Fewest periods a short narrow sweep holds: the analysis needs 20 periods
/// found along the main sweep (`identify`'s preparation), and the fades'
/// quiet ends hold some that are not found.
pub const MIN_NARROW_PERIODS: f64 = 30.0;

/// Length (s) of a log sweep over `band_oct` octaves around a resonance at
/// `f_hz` with quality `q` that crosses its half-power bandwidth in
/// [`N_TAU`] decay times: rate r (oct/s) gives df/dt = f ln2 r, the
/// bandwidth f/Q is crossed in 1/(Q ln2 r) >= N tau = N Q/(pi f). At least
/// [`MIN_NARROW_PERIODS`] periods (a log sweep from f1 to f2 in T holds
/// T (f2 - f1) / ln(f2/f1) of them) and [`MIN_NARROW_S`].
pub fn narrow_duration_s(f_hz: f64, q: f64, below_oct: f64, above_oct: f64) -> f64 {
    let band_oct = below_oct + above_oct;
    let rate_oct_per_s = std::f64::consts::PI * f_hz / (N_TAU * q * q * std::f64::consts::LN_2);
    let (f1, f2) = (f_hz * 2f64.powf(-below_oct), f_hz * 2f64.powf(above_oct));
    let for_periods = MIN_NARROW_PERIODS * (f2 / f1).ln() / (f2 - f1);
    (band_oct / rate_oct_per_s)
        .max(for_periods)
        .max(MIN_NARROW_S)
}

/// Peak |x| of a linear resonator (resonance `f_hz`, quality `q`, unit
/// static gain) driven by `spec`: a short sweep builds up less of the
/// resonance than a slow one. The ratio of two such peaks turns the drive a
/// golden unit needed in the full procedure's sweep into the drive of the
/// short one (the part's response around its resonance is what limits the
/// build-up; the exciter and box are smooth there).
pub fn resonator_peak(spec: &SweepSpec, f_hz: f64, q: f64) -> f64 {
    let w0 = 2.0 * std::f64::consts::PI * f_hz;
    let (w2, d) = (w0 * w0, w0 / q);
    // 40 steps per period of the highest frequency involved (RK4).
    let dt = 1.0 / (40.0 * spec.f_end_hz.max(f_hz));
    let n = (spec.total_s() / dt).ceil() as usize;
    let acc = |t: f64, x: f64, v: f64| w2 * spec.value(t) - d * v - w2 * x;
    let (mut x, mut v, mut peak) = (0.0f64, 0.0f64, 0.0f64);
    for k in 0..n {
        let t = k as f64 * dt;
        let (k1x, k1v) = (v, acc(t, x, v));
        let (k2x, k2v) = (
            v + 0.5 * dt * k1v,
            acc(t + 0.5 * dt, x + 0.5 * dt * k1x, v + 0.5 * dt * k1v),
        );
        let (k3x, k3v) = (
            v + 0.5 * dt * k2v,
            acc(t + 0.5 * dt, x + 0.5 * dt * k2x, v + 0.5 * dt * k2v),
        );
        let (k4x, k4v) = (v + dt * k3v, acc(t + dt, x + dt * k3x, v + dt * k3v));
        x += dt / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
        v += dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        peak = peak.max(x.abs());
    }
    peak
}

/// The drive of `short` that builds up the resonance (`f_hz`, `q`) as far
/// as `drive_v` did in `slow`.
fn equivalent_drive(drive_v: f64, slow: &SweepSpec, short: &SweepSpec, f_hz: f64, q: f64) -> f64 {
    let unit = |s: &SweepSpec| SweepSpec {
        amplitude_v: 1.0,
        ..*s
    };
    let (ps, pf) = (
        resonator_peak(&unit(slow), f_hz, q),
        resonator_peak(&unit(short), f_hz, q),
    );
    if ps > 0.0 && pf > 0.0 {
        drive_v * ps / pf
    } else {
        drive_v
    }
}

/// Runs the production procedure on `bench` with the golden units'
/// reference; without one, or when the part is too far from it, the full
/// procedure ([`super::run`]) measures it and the outcome says why.
pub fn run_production(
    bench: &mut dyn Bench,
    cfg: &ProcedureConfig,
    golden: Option<&GoldenReference>,
    obs: &mut dyn Observer,
) -> Result<Outcome, ProcedureError> {
    let limits = bench.limits();
    validate(cfg, &limits)?;
    let Some(g) = golden else {
        return run_full_instead(
            bench,
            cfg,
            obs,
            "the recipe has no golden reference yet (approve a limit proposal from golden units)"
                .into(),
        );
    };
    if let Err(e) = g.validate(cfg.levels_m.len()) {
        let msgs: Vec<String> = e.iter().map(|(f, m)| format!("{f}: {m}")).collect();
        return Err(ProcedureError::Invalid(format!(
            "golden reference: {}",
            msgs.join("; ")
        )));
    }
    let fs = bench.sample_rate_hz();
    let vmax = limits.max_drive_v;
    let narrow_s: Vec<f64> = g
        .levels
        .iter()
        .map(|l| {
            narrow_duration_s(l.resonance_hz, g.q, NARROW_BELOW_OCT, NARROW_ABOVE_OCT)
                .min(cfg.narrow_duration_s)
        })
        .collect();
    let est_total_s = PRE_S + SHORT_SILENCE_S + narrow_s.iter().map(|d| d + 0.5).sum::<f64>();
    let mut cx = Ctx {
        bench,
        obs,
        fs,
        limits,
        elapsed_s: 0.0,
        est_total_s,
        log: vec![format!(
            "production procedure: golden f0 {:.2} Hz, Q {:.2} ({} units)",
            g.f0_hz, g.q, g.units
        )],
    };
    cx.obs.progress(Step::PreMeasurement, 0.0, est_total_s);

    // (1) Short pre-measurement with level check.
    let target_pre = cfg.pre_target_x_m;
    let pre_spec_at = |v: f64| {
        let mut spec = SweepSpec::new(
            g.f0_hz * 2f64.powf(-PRE_OCT),
            g.f0_hz * 2f64.powf(PRE_OCT),
            PRE_S,
            v,
        );
        spec.silence_s = SHORT_SILENCE_S;
        spec
    };
    // The level the golden units' full pre-measurement built up: the same
    // amplitude at resonance gives the same small-signal k0 on a part whose
    // K(x) already bends at 1 mm.
    let full_pre = SweepSpec::new(
        cfg.pre_f_start_hz,
        cfg.pre_f_end_hz,
        cfg.pre_duration_s,
        1.0,
    );
    // The build-up is the drive-to-displacement response's (exciter and box
    // included), as the golden units' full pre-measurement showed it.
    let q_pre = g.pre_q_drive_to_x.unwrap_or(g.q);
    let mut pre_v =
        equivalent_drive(g.pre_drive_v, &full_pre, &pre_spec_at(1.0), g.f0_hz, q_pre).min(vmax);
    cx.log.push(format!(
        "pre-measurement drive {pre_v:.3} V: the golden units' {:.3} V in the full procedure's sweep",
        g.pre_drive_v
    ));
    let mut pre = None;
    for attempt in 0..3 {
        let spec = pre_spec_at(pre_v);
        let played = cx.play(Step::PreMeasurement, &spec, false)?;
        if let Stop::Limit = played.stop {
            cx.log.push(format!(
                "short pre-measurement at {pre_v:.3} V hit the displacement limit"
            ));
            pre_v /= 4.0;
            continue;
        }
        let info = analyse(&spec, &played.sig)
            .ok_or_else(|| ProcedureError::Failed("short pre-measurement too short".into()))?;
        let ratio = info.x_fund_peak_m / target_pre;
        cx.log.push(format!(
            "short pre-measurement {:.2}-{:.2} Hz in {PRE_S} s at {pre_v:.3} V: x peak {:.3} mm (target {:.3} mm)",
            spec.f_start_hz,
            spec.f_end_hz,
            info.x_fund_peak_m * 1e3,
            target_pre * 1e3
        ));
        let ok = (0.5..=2.0).contains(&ratio) || attempt == 2 || (ratio < 0.5 && pre_v >= vmax);
        if ok || info.x_fund_peak_m <= 0.0 {
            pre = Some((spec, played.sig, info.q_drive_to_x));
            break;
        }
        pre_v = (pre_v / ratio).min(vmax);
        cx.log.push(format!("level far off: redo at {pre_v:.3} V"));
    }
    let Some((pre_spec, pre_sig, pre_q)) = pre else {
        return give_up(
            cx,
            cfg,
            "the short pre-measurement kept hitting the displacement limit".into(),
        );
    };
    let f0 = match springbench_core::identify::small_signal_fit(&pre_sig, cfg.moving_mass_kg)
        .ok()
        .and_then(|f| f.result.f0_hz)
    {
        Some(f) => f,
        None => {
            return give_up(
                cx,
                cfg,
                "the short pre-measurement gave no small-signal f0".into(),
            );
        }
    };
    let dev_percent = 100.0 * (f0 / g.f0_hz - 1.0);
    cx.log.push(format!(
        "small-signal f0 {f0:.2} Hz: {dev_percent:+.1} % from the golden units' {:.2} Hz",
        g.f0_hz
    ));
    if dev_percent.abs() > g.max_f0_deviation_percent {
        return give_up(
            cx,
            cfg,
            format!(
                "small-signal f0 {f0:.2} Hz is {dev_percent:+.1} % from the golden units' {:.2} Hz (more than {} %)",
                g.f0_hz, g.max_f0_deviation_percent
            ),
        );
    }

    // (2) One short rising sweep per level (a second one when the level is off).
    let scale = f0 / g.f0_hz;
    let mut narrow = Vec::new();
    for (li, &level) in cfg.levels_m.iter().enumerate() {
        let gl = &g.levels[li];
        let f_r = gl.resonance_hz * scale;
        let band = |d: f64, v: f64| {
            SweepSpec::new(
                f_r * 2f64.powf(-NARROW_BELOW_OCT),
                f_r * 2f64.powf(NARROW_ABOVE_OCT),
                d,
                v,
            )
        };
        // The golden drive is where the full search stopped, anywhere within
        // its tolerance of its aim: aimed like the full procedure (above the
        // target, so that the excursion reaches it on both sides) with the
        // golden units' own Xpeak at that drive.
        let aim = gl.xpeak_m.map_or(1.0, |x| {
            let aim = (aim_m(level) / x).clamp(0.5, 2.0);
            cx.log.push(format!(
                "golden drive {:.3} V reached Xpeak {:.3} mm: aimed at {:.3} mm with x{aim:.4}",
                gl.drive_v,
                x * 1e3,
                aim_m(level) * 1e3
            ));
            aim
        });
        let mut v = equivalent_drive(
            gl.drive_v * aim,
            &band(cfg.narrow_duration_s, 1.0),
            &band(narrow_s[li], 1.0),
            f_r,
            g.q,
        )
        .min(vmax);
        let mut done = None;
        let mut lowered = false;
        let mut corrected = false;
        for _ in 0..4 {
            let spec = band(narrow_s[li], v);
            let played = cx.play(Step::NarrowSweep, &spec, false)?;
            if let Stop::Limit = played.stop {
                lowered = true;
                v *= 0.8;
                cx.log.push(format!(
                    "short narrow sweep hit the displacement limit: redo at {v:.3} V"
                ));
                continue;
            }
            let mut info = analyse(&spec, &played.sig)
                .ok_or_else(|| ProcedureError::Failed("short narrow sweep too short".into()))?;
            // The level is checked with the analysis's own Xpeak, so the short
            // procedure accepts the sweeps the analysis reads as on target.
            match springbench_core::identify::sweep_xpeak_m(&played.sig, cfg.moving_mass_kg)
                .and_then(|x| {
                    springbench_core::identify::sweep_reach_m(&played.sig, cfg.moving_mass_kg)
                        .map(|r| (x, r))
                }) {
                Ok((x, r)) => {
                    info.xpeak_m = x;
                    info.reach_m = r;
                }
                Err(e) => cx.log.push(format!(
                    "Xpeak from the raw samples ({:.3} mm): the analysis's preparation failed: {e}",
                    info.xpeak_m * 1e3
                )),
            }
            cx.log.push(format!(
                "short narrow sweep {:.2}-{:.2} Hz in {:.2} s at {v:.3} V: Xpeak {:.3} mm, reached +-{:.3} mm (target {:.3} mm), resonance {:.2} Hz",
                spec.f_start_hz,
                spec.f_end_hz,
                spec.duration_s,
                info.xpeak_m * 1e3,
                info.reach_m * 1e3,
                level * 1e3,
                info.resonance_hz
            ));
            // The upper branch is ridden only from at least 1/3 octave below
            // the large-signal resonance, and the sweep must cross it (|X/Mic|
            // falls below the half-power point after its peak).
            let lo = spec.f_start_hz * 2f64.powf(1.0 / 3.0);
            if info.resonance_hz < lo || !info.crossed {
                let why = if info.crossed {
                    format!(
                        "less than 1/3 octave above the sweep's start {:.2} Hz",
                        spec.f_start_hz
                    )
                } else {
                    format!(
                        "not crossed by the short sweep up to {:.2} Hz",
                        spec.f_end_hz
                    )
                };
                return give_up(
                    cx,
                    cfg,
                    format!(
                        "large-signal resonance {:.2} Hz at level {} {why}",
                        info.resonance_hz,
                        li + 1
                    ),
                );
            }
            // The excursion on both sides against the aim: off when it
            // falls short of the target by more than the analysis's margin
            // for Keff at the target (`validity::TARGET_MARGIN`), or
            // overshoots the aim by more than the search tolerance.
            let ratio = aim_m(level) / info.reach_m.max(1e-9);
            let off = info.reach_m < level * (1.0 - TARGET_MARGIN)
                || info.reach_m > aim_m(level) / (1.0 - SEARCH_TOL);
            if off && !corrected && !lowered {
                let nv = (v * ratio.clamp(0.5, 2.0)).min(vmax);
                if nv != v {
                    corrected = true;
                    v = nv;
                    cx.log.push(format!(
                        "the excursion {:.0} % of the aim: one more sweep at {v:.3} V",
                        100.0 / ratio
                    ));
                    continue;
                }
            }
            if off && !lowered {
                // Two short sweeps did not hit the level: the part is too far
                // from the golden units for their drive; the full search decides
                // (and says when the target cannot be reached).
                return give_up(
                    cx,
                    cfg,
                    format!(
                        "the excursion +-{:.3} mm at level {} is {:.0} % of the aim {:.3} mm (target {:.3} mm) at {v:.3} V{}",
                        info.reach_m * 1e3,
                        li + 1,
                        100.0 / ratio,
                        aim_m(level) * 1e3,
                        level * 1e3,
                        if corrected { " in the corrected short sweep" } else { " (drive limit)" }
                    ),
                );
            }
            done = Some(cx.keep_narrow(level, v, lowered, spec, &info, played.sig));
            break;
        }
        narrow.push(done.ok_or_else(|| {
            ProcedureError::Failed(format!(
                "short narrow sweep for Xpeak {level} m kept hitting the displacement limit"
            ))
        })?);
    }
    // Handed out only now: before this the short procedure may still fall
    // back to the full one, which measures every level again.
    let pre = super::PreMeasured {
        signals: &pre_sig,
        sweep: &pre_spec,
        f0_hz: f0,
        q_drive_to_x: pre_q,
    };
    let mut kept = Vec::new();
    for (li, sweep) in narrow.into_iter().enumerate() {
        cx.hand_out(&pre, li, sweep, &mut kept)?;
    }
    let narrow = kept;
    let bench_time_s = cx.elapsed_s;
    cx.log.push(format!("bench time {bench_time_s:.2} s"));
    cx.obs.progress(Step::Fit, 1.0, 0.0);
    Ok(Outcome {
        pre: pre_sig,
        pre_sweep: pre_spec,
        f0_hz: f0,
        pre_q_drive_to_x: pre_q,
        narrow,
        bench_time_s,
        log: cx.log,
        production: Some(ProductionRun {
            fallback: None,
            short_bench_time_s: bench_time_s,
        }),
    })
}

/// The full procedure after what the short one played in `cx`, saying why.
fn give_up(cx: Ctx<'_>, cfg: &ProcedureConfig, why: String) -> Result<Outcome, ProcedureError> {
    fall_back(cx.bench, cfg, cx.obs, cx.elapsed_s, cx.log, why)
}

/// The full procedure instead of the production one, for `why` (no golden
/// reference, or a recipe that judges what the short sweeps cannot
/// measure); the outcome says so as a fall-back.
pub fn run_full_instead(
    bench: &mut dyn Bench,
    cfg: &ProcedureConfig,
    obs: &mut dyn Observer,
    why: String,
) -> Result<Outcome, ProcedureError> {
    fall_back(bench, cfg, obs, 0.0, vec![], why)
}

/// The full procedure after `spent_s` of the short one, saying why.
fn fall_back(
    bench: &mut dyn Bench,
    cfg: &ProcedureConfig,
    obs: &mut dyn Observer,
    spent_s: f64,
    mut log: Vec<String>,
    why: String,
) -> Result<Outcome, ProcedureError> {
    log.push(format!("falls back to the full procedure: {why}"));
    let mut out = super::run(bench, cfg, obs)?;
    log.append(&mut out.log);
    out.log = log;
    out.bench_time_s += spent_s;
    out.production = Some(ProductionRun {
        fallback: Some(why),
        short_bench_time_s: spent_s,
    });
    Ok(out)
}
