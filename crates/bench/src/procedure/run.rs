//! The standard procedure: level probe, pre-measurement with level check,
//! resonance search with short rising sweeps, narrow rising sweep per level.

use super::sweep::{abs, cycles, div, Cycle, SweepSpec};
use super::{NarrowSweep, Observer, Outcome, PreMeasured, ProcedureConfig, ProcedureError, Step};
use crate::{Bench, BenchError, Block, Control, Limits};
use springbench_core::recording::Signals;

/// Level probe: a short wide-band sweep at a low, safe level.
const PROBE_S: f64 = 2.0;
const PROBE_V: f64 = 0.5;
/// Resonance search sweeps: one octave (1/3 below to 2/3 above the estimate) in this time.
pub(super) const SEARCH_S: f64 = 3.0;
pub(super) const MAX_SEARCH: usize = 3;
/// Silence after probe and search sweeps (s).
pub(super) const SHORT_SILENCE_S: f64 = 0.2;
/// Xpeak within this fraction of the target ends the search.
pub(super) const SEARCH_TOL: f64 = 0.08;

/// The excursion the level control aims at for a target Xpeak: above the
/// target by the search tolerance, so that a sweep accepted within the
/// tolerance reaches the target on both sides (its half peak-to-peak, see
/// [`SweepInfo::reach_m`], is at least the target). Keff at the target is
/// read over c +- target (c the excursion's centre): aimed at the target
/// itself, a hardening spider_4in stopped at 7.5 mm of 8 on its larger side
/// and 6.75 mm on the other, and every good part's Keff at the target was
/// extrapolated beyond the measured range (issue 35).
pub(super) fn aim_m(target_m: f64) -> f64 {
    target_m * (1.0 + SEARCH_TOL)
}
/// Narrow sweep: this many octaves below and above the large-signal resonance found.
pub(super) const NARROW_BELOW_OCT: f64 = 0.45;
pub(super) const NARROW_ABOVE_OCT: f64 = 0.4;

pub(super) enum Stop {
    Completed,
    Limit,
    Early,
}

pub(super) struct Played {
    /// The bench's record of a completed sweep, or what was captured of a
    /// sweep that stopped early ([`Stop::Early`]). A sweep that hit the
    /// limit ([`Stop::Limit`]) is never analysed (it is played again): its
    /// record is empty unless it was played with `early_stop`.
    pub(super) sig: Signals,
    pub(super) stop: Stop,
}

pub(super) struct Ctx<'a> {
    pub(super) bench: &'a mut dyn Bench,
    pub(super) obs: &'a mut dyn Observer,
    pub(super) fs: f64,
    pub(super) limits: Limits,
    pub(super) elapsed_s: f64,
    pub(super) est_total_s: f64,
    pub(super) log: Vec<String>,
}

impl Ctx<'_> {
    pub(super) fn play(
        &mut self,
        step: Step,
        spec: &SweepSpec,
        early_stop: bool,
    ) -> Result<Played, ProcedureError> {
        spec.validate().map_err(ProcedureError::Failed)?;
        let fs = self.fs;
        let drive = spec.samples(fs);
        let limit = self.limits.max_displacement_m;
        // A copy of the blocks is kept only where it can be analysed: a
        // sweep that may stop early. A completed sweep is the bench's own
        // record; copying every sweep held it twice (38 MB for a 16 s
        // pre-measurement at 48 kHz).
        let (mut xs, mut mics, mut drv) = (Vec::new(), Vec::new(), Vec::new());
        let mut captured = 0usize;
        let mut why: Option<Stop> = None;
        let mut cancelled = false;
        let mut block_max: Vec<(f64, f64)> = Vec::new(); // (t_end, max |x|)
        let (mut env_max, mut t_env_max) = (0.0f64, 0.0f64);
        let elapsed0 = self.elapsed_s;
        let est_total = self.est_total_s.max(elapsed0 + spec.total_s());
        let obs = &mut *self.obs;
        let bench = &mut *self.bench;
        let mut cb = |b: Block<'_>| -> Control {
            captured += b.displacement_m.len();
            if early_stop {
                xs.extend_from_slice(b.displacement_m);
                mics.extend_from_slice(b.microphone_v);
                drv.extend_from_slice(b.drive_v);
            }
            if why.is_some() || cancelled {
                return Control::Abort;
            }
            obs.samples(step, b);
            let t = (b.start_sample + b.displacement_m.len()) as f64 / fs;
            obs.progress(
                step,
                ((elapsed0 + t) / est_total).min(0.99),
                (est_total - elapsed0 - t).max(0.0),
            );
            if obs.cancelled() {
                cancelled = true;
                return Control::Abort;
            }
            let m = b.displacement_m.iter().fold(0.0f64, |a, x| a.max(x.abs()));
            if m > limit {
                why = Some(Stop::Limit);
                return Control::Abort;
            }
            if early_stop && t < spec.duration_s {
                block_max.push((t, m));
                let period = 1.0 / spec.freq_at(t);
                let env = block_max
                    .iter()
                    .rev()
                    .take_while(|(tb, _)| t - tb < 1.5 * period)
                    .fold(0.0f64, |a, (_, v)| a.max(*v));
                if env > env_max {
                    env_max = env;
                    t_env_max = t;
                }
                if t > spec.fade_s + 3.0 * period
                    && t - t_env_max > 3.0 * period
                    && env < 0.5 * env_max
                {
                    why = Some(Stop::Early);
                    return Control::Abort;
                }
            }
            Control::Continue
        };
        let res = bench.run(&drive, &mut cb);
        self.elapsed_s += captured as f64 / fs;
        let partial = Signals {
            sample_rate_hz: fs,
            displacement_m: xs,
            microphone_v: mics,
            drive_v: Some(drv),
        };
        match res {
            Ok(sig) => Ok(Played {
                sig,
                stop: Stop::Completed,
            }),
            Err(BenchError::Aborted) if cancelled => Err(ProcedureError::Cancelled),
            Err(BenchError::Aborted) => Ok(Played {
                sig: partial,
                stop: why.unwrap_or(Stop::Limit),
            }),
            Err(BenchError::LaserOutOfRange { .. }) => Ok(Played {
                sig: partial,
                stop: Stop::Limit,
            }),
            Err(e) => Err(e.into()),
        }
    }
}

impl Ctx<'_> {
    /// Hands the finished narrow sweep of level `index` to the observer;
    /// kept in `narrow` unless the observer took it.
    pub(super) fn hand_out(
        &mut self,
        pre: &PreMeasured<'_>,
        index: usize,
        sweep: NarrowSweep,
        narrow: &mut Vec<NarrowSweep>,
    ) -> Result<(), ProcedureError> {
        if let Some(s) = self.obs.narrow_finished(&*self.bench, pre, index, sweep)? {
            narrow.push(s);
        }
        Ok(())
    }

    /// The narrow sweep kept for `level` at drive `v`, with its warning
    /// (logged) when the target was not reached.
    pub(super) fn keep_narrow(
        &mut self,
        level: f64,
        v: f64,
        lowered: bool,
        spec: SweepSpec,
        info: &SweepInfo,
        signals: Signals,
    ) -> NarrowSweep {
        let warning = target_warning(level, info.xpeak_m, v, self.limits.max_drive_v, lowered);
        if let Some(w) = &warning {
            self.log.push(w.clone());
        }
        NarrowSweep {
            warning,
            target_xpeak_m: level,
            drive_v: v,
            f_start_hz: spec.f_start_hz,
            f_end_hz: spec.f_end_hz,
            sweep: spec,
            resonance_hz: info.resonance_hz,
            xpeak_m: info.xpeak_m,
            signals,
        }
    }
}

/// What a sweep tells: fundamental amplitude peak, resonance, gain.
pub(super) struct SweepInfo {
    /// Largest fundamental amplitude of x (m).
    pub(super) x_fund_peak_m: f64,
    /// Largest |x| (m); the production procedure replaces it with the
    /// analysis's Xpeak (`identify::sweep_xpeak_m`) before its level check.
    pub(super) xpeak_m: f64,
    /// Half the peak-to-peak excursion (m): how far the sweep reached on
    /// both sides of its centre. The level control checks this one; the
    /// production procedure replaces it with the analysis's at the resonance
    /// (`identify::sweep_reach_m`).
    pub(super) reach_m: f64,
    /// Peak of |X/Mic| (Hz).
    pub(super) resonance_hz: f64,
    /// |X/U| at the resonance (m/V).
    pub(super) gain_m_per_v: f64,
    /// |X/Mic| fell below 1/sqrt(2) of its peak after the peak (within the
    /// faded-in part): the sweep crossed the resonance.
    pub(super) crossed: bool,
    /// Quality of |X/U| (drive to displacement) around its peak: the peak
    /// frequency over its half-power bandwidth; None when the sweep does not
    /// reach both half-power points.
    pub(super) q_drive_to_x: Option<f64>,
}

fn smooth(c: &[Cycle], i: usize, ch: usize, half: usize) -> (f64, f64) {
    let lo = i.saturating_sub(half);
    let hi = (i + half + 1).min(c.len());
    let (mut re, mut im) = (0.0, 0.0);
    for cy in &c[lo..hi] {
        re += cy.amp[ch].0;
        im += cy.amp[ch].1;
    }
    let n = (hi - lo) as f64;
    (re / n, im / n)
}

pub(super) fn analyse(spec: &SweepSpec, sig: &Signals) -> Option<SweepInfo> {
    let drive = sig.drive_v.as_deref()?;
    let cyc = cycles(
        spec,
        sig.sample_rate_hz,
        &[&sig.displacement_m, &sig.microphone_v, drive],
    );
    // Fully faded-in part only.
    let lo_t = spec.fade_s;
    let hi_t = spec.duration_s - spec.fade_s;
    let idx: Vec<usize> = (0..cyc.len())
        .filter(|&i| cyc[i].t_s > lo_t && cyc[i].t_s < hi_t)
        .collect();
    if idx.is_empty() {
        return None;
    }
    let mut best = (f64::NEG_INFINITY, 0usize);
    let mut x_fund_peak: f64 = 0.0;
    let mut hs = Vec::with_capacity(idx.len());
    for &i in &idx {
        let x = smooth(&cyc, i, 0, 2);
        let m = smooth(&cyc, i, 1, 2);
        x_fund_peak = x_fund_peak.max(abs(x));
        let h = abs(div(x, m));
        hs.push((i, h));
        if h.is_finite() && h > best.0 {
            best = (h, i);
        }
    }
    let i = best.1;
    // The sweep crossed the resonance when |X/Mic| fell below its half-power
    // point after the peak (the fade-out included: a ratio of two channels
    // does not depend on the drive's amplitude).
    let half = best.0 * std::f64::consts::FRAC_1_SQRT_2;
    let crossed = (i + 1..cyc.len())
        .filter(|&j| cyc[j].t_s < spec.duration_s)
        .any(|j| abs(div(smooth(&cyc, j, 0, 2), smooth(&cyc, j, 1, 2))) < half);
    // |X/U| and its half-power points around its peak (faded-in part).
    let gu: Vec<(f64, f64)> = idx
        .iter()
        .map(|&j| {
            (
                cyc[j].f_hz,
                abs(div(smooth(&cyc, j, 0, 2), smooth(&cyc, j, 2, 2))),
            )
        })
        .collect();
    let q_drive_to_x = gu
        .iter()
        .enumerate()
        .filter(|(_, (_, g))| g.is_finite())
        .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
        .and_then(|(k, &(fp, gp))| {
            let h = gp * std::f64::consts::FRAC_1_SQRT_2;
            let lo = gu[..k].iter().rev().find(|(_, g)| *g < h)?.0;
            let hi = gu[k..].iter().find(|(_, g)| *g < h)?.0;
            (hi > lo).then(|| fp / (hi - lo))
        });
    let g = abs(div(smooth(&cyc, i, 0, 2), smooth(&cyc, i, 2, 2)));
    Some(SweepInfo {
        x_fund_peak_m: x_fund_peak,
        xpeak_m: sig
            .displacement_m
            .iter()
            .fold(0.0f64, |a, x| a.max(x.abs())),
        reach_m: {
            let (lo, hi) = sig
                .displacement_m
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
                    (l.min(x), h.max(x))
                });
            if hi >= lo {
                0.5 * (hi - lo)
            } else {
                0.0
            }
        },
        resonance_hz: cyc[i].f_hz,
        gain_m_per_v: g,
        crossed,
        q_drive_to_x,
    })
}

/// The warning of a narrow sweep whose Xpeak stayed more than the search
/// tolerance below its target; None when the target was reached.
fn target_warning(
    target_m: f64,
    reached_m: f64,
    drive_v: f64,
    max_drive_v: f64,
    lowered_for_displacement: bool,
) -> Option<String> {
    if reached_m >= (1.0 - SEARCH_TOL) * target_m {
        return None;
    }
    let why = if drive_v >= max_drive_v * (1.0 - 1e-9) {
        format!("the drive is at its limit of {max_drive_v} V")
    } else if lowered_for_displacement {
        "the drive was lowered after the sweep hit the displacement limit".to_string()
    } else {
        format!("the resonance search ended at {drive_v:.3} V")
    };
    Some(format!(
        "target Xpeak {:.3} mm not reached within the limits: reached {:.3} mm ({:.0} % of the target; {why})",
        target_m * 1e3,
        reached_m * 1e3,
        100.0 * reached_m / target_m
    ))
}

pub(super) fn validate(cfg: &ProcedureConfig, limits: &Limits) -> Result<(), ProcedureError> {
    let bad = |m: String| Err(ProcedureError::Invalid(m));
    if !(cfg.moving_mass_kg.is_finite() && cfg.moving_mass_kg > 0.0) {
        return bad(format!(
            "moving_mass_kg must be positive, got {}",
            cfg.moving_mass_kg
        ));
    }
    if cfg.levels_m.is_empty() {
        return bad("levels_m must hold at least one target Xpeak".into());
    }
    for &l in &cfg.levels_m {
        if !(l.is_finite() && l > 0.0) {
            return bad(format!("target Xpeak must be positive, got {l} m"));
        }
        if l > limits.max_displacement_m {
            return bad(format!(
                "target Xpeak {l} m is beyond the bench's displacement limit {} m",
                limits.max_displacement_m
            ));
        }
    }
    if !(cfg.pre_target_x_m.is_finite()
        && cfg.pre_target_x_m > 0.0
        && cfg.pre_target_x_m < limits.max_displacement_m)
    {
        return bad(format!(
            "pre_target_x_m must be positive and below the displacement limit, got {}",
            cfg.pre_target_x_m
        ));
    }
    if !(cfg.pre_f_start_hz > 0.0
        && cfg.pre_f_end_hz > cfg.pre_f_start_hz
        && cfg.pre_f_end_hz.is_finite())
    {
        return bad(format!(
            "pre-measurement needs 0 < pre_f_start_hz < pre_f_end_hz, got {} .. {}",
            cfg.pre_f_start_hz, cfg.pre_f_end_hz
        ));
    }
    for (n, d) in [
        ("pre_duration_s", cfg.pre_duration_s),
        ("narrow_duration_s", cfg.narrow_duration_s),
    ] {
        if !(d.is_finite() && (1.0..=600.0).contains(&d)) {
            return bad(format!("{n} must be 1..600 s, got {d}"));
        }
    }
    Ok(())
}

/// Runs the standard procedure on `bench`.
pub fn run(
    bench: &mut dyn Bench,
    cfg: &ProcedureConfig,
    obs: &mut dyn Observer,
) -> Result<Outcome, ProcedureError> {
    let limits = bench.limits();
    validate(cfg, &limits)?;
    let fs = bench.sample_rate_hz();
    let est_total_s = PROBE_S
        + SHORT_SILENCE_S
        + cfg.pre_duration_s
        + 0.5
        + cfg.levels_m.len() as f64
            * (MAX_SEARCH as f64 * (SEARCH_S + SHORT_SILENCE_S) + cfg.narrow_duration_s + 0.5);
    let mut cx = Ctx {
        bench,
        obs,
        fs,
        limits,
        elapsed_s: 0.0,
        est_total_s,
        log: Vec::new(),
    };
    let vmax = limits.max_drive_v;
    let target_pre = cfg.pre_target_x_m;

    // (1a) Level probe: short wide-band sweep, raised until the part moves.
    cx.obs.progress(Step::PreMeasurement, 0.0, est_total_s);
    let mut v = PROBE_V.min(vmax);
    let mut pre_v = None;
    for _ in 0..4 {
        let mut spec = SweepSpec::new(cfg.pre_f_start_hz, cfg.pre_f_end_hz, PROBE_S, v);
        spec.silence_s = SHORT_SILENCE_S;
        let played = cx.play(Step::PreMeasurement, &spec, false)?;
        if let Stop::Limit = played.stop {
            cx.log
                .push(format!("probe at {v:.3} V hit the displacement limit"));
            v /= 10.0;
            continue;
        }
        let info = analyse(&spec, &played.sig)
            .ok_or_else(|| ProcedureError::Failed("probe sweep too short".into()))?;
        cx.log.push(format!(
            "probe at {v:.3} V: fundamental peak {:.3} mm near {:.1} Hz",
            info.x_fund_peak_m * 1e3,
            info.resonance_hz
        ));
        if info.x_fund_peak_m < 0.03 * target_pre {
            if v >= vmax {
                break;
            }
            v = (v * 10.0).min(vmax);
            continue;
        }
        pre_v = Some((v * target_pre / info.x_fund_peak_m).min(vmax));
        break;
    }
    let mut pre_v = pre_v.unwrap_or(v);

    // (1b) Pre-measurement with level check; redo once at a corrected level if far off.
    let mut pre = None;
    for attempt in 0..3 {
        let spec = SweepSpec::new(
            cfg.pre_f_start_hz,
            cfg.pre_f_end_hz,
            cfg.pre_duration_s,
            pre_v,
        );
        let played = cx.play(Step::PreMeasurement, &spec, false)?;
        if let Stop::Limit = played.stop {
            cx.log.push(format!(
                "pre-measurement at {pre_v:.3} V hit the displacement limit"
            ));
            pre_v /= 4.0;
            continue;
        }
        let info = analyse(&spec, &played.sig)
            .ok_or_else(|| ProcedureError::Failed("pre-measurement too short".into()))?;
        let ratio = info.x_fund_peak_m / target_pre;
        cx.log.push(format!(
            "pre-measurement at {pre_v:.3} V: x peak {:.3} mm (target {:.3} mm), f0 {:.2} Hz",
            info.x_fund_peak_m * 1e3,
            target_pre * 1e3,
            info.resonance_hz
        ));
        let ok = (0.5..=2.0).contains(&ratio) || attempt == 2 || (ratio < 0.5 && pre_v >= vmax);
        if ok || info.x_fund_peak_m <= 0.0 {
            pre = Some((spec, played.sig, info));
            break;
        }
        pre_v = (pre_v / ratio).min(vmax);
        cx.log.push(format!("level far off: redo at {pre_v:.3} V"));
    }
    let (pre_spec, pre_sig, pre_info) = pre.ok_or_else(|| {
        ProcedureError::Failed("pre-measurement kept hitting the displacement limit".into())
    })?;

    // (2) + (3) per level: resonance search, narrow sweep.
    let mut narrow = Vec::new();
    let mut f_r = pre_info.resonance_hz;
    let mut v = (cfg.levels_m[0] / pre_info.gain_m_per_v.max(1e-12)).min(vmax);
    let mut last_level = cfg.levels_m[0];
    let pre = PreMeasured {
        signals: &pre_sig,
        sweep: &pre_spec,
        f0_hz: pre_info.resonance_hz,
        q_drive_to_x: pre_info.q_drive_to_x,
    };
    for (li, &level) in cfg.levels_m.iter().enumerate() {
        v = (v * level / last_level).min(vmax);
        last_level = level;
        for i in 0..MAX_SEARCH {
            let mut spec = SweepSpec::new(
                f_r * 2f64.powf(-1.0 / 3.0),
                f_r * 2f64.powf(2.0 / 3.0),
                SEARCH_S,
                v,
            );
            spec.silence_s = SHORT_SILENCE_S;
            let played = cx.play(Step::ResonanceSearch, &spec, true)?;
            if let Stop::Limit = played.stop {
                v *= 0.5;
                cx.log.push(format!(
                    "search {i}: displacement limit reached, drive lowered to {v:.3} V"
                ));
                continue;
            }
            let Some(info) = analyse(&spec, &played.sig) else {
                continue;
            };
            f_r = info.resonance_hz;
            let ratio = aim_m(level) / info.reach_m.max(1e-9);
            cx.log.push(format!(
                "search {i} at {v:.3} V: Xpeak {:.3} mm, reached +-{:.3} mm (aim {:.3} mm), resonance {:.2} Hz{}",
                info.xpeak_m * 1e3,
                info.reach_m * 1e3,
                aim_m(level) * 1e3,
                f_r,
                if let Stop::Early = played.stop {
                    " (stopped after the jump)"
                } else {
                    ""
                }
            ));
            if (ratio - 1.0).abs() < SEARCH_TOL {
                break;
            }
            let nv = (v * ratio.clamp(0.33, 3.0)).min(vmax);
            if nv == v {
                cx.log.push(format!("drive limit {vmax} V reached"));
                break;
            }
            v = nv;
        }
        // Narrow sweep; if it hits the limit, lower the drive and redo.
        let mut done = None;
        let mut lowered = false;
        for _ in 0..3 {
            let spec = SweepSpec::new(
                f_r * 2f64.powf(-NARROW_BELOW_OCT),
                f_r * 2f64.powf(NARROW_ABOVE_OCT),
                cfg.narrow_duration_s,
                v,
            );
            let played = cx.play(Step::NarrowSweep, &spec, false)?;
            if let Stop::Limit = played.stop {
                lowered = true;
                v *= 0.8;
                cx.log.push(format!(
                    "narrow sweep hit the displacement limit: redo at {v:.3} V"
                ));
                continue;
            }
            let info = analyse(&spec, &played.sig)
                .ok_or_else(|| ProcedureError::Failed("narrow sweep too short".into()))?;
            cx.log.push(format!(
                "narrow sweep {:.2}-{:.2} Hz at {v:.3} V: Xpeak {:.3} mm, reached +-{:.3} mm (target {:.3} mm), resonance {:.2} Hz",
                spec.f_start_hz,
                spec.f_end_hz,
                info.xpeak_m * 1e3,
                info.reach_m * 1e3,
                level * 1e3,
                info.resonance_hz
            ));
            done = Some(cx.keep_narrow(level, v, lowered, spec, &info, played.sig));
            break;
        }
        let sweep = done.ok_or_else(|| {
            ProcedureError::Failed(format!(
                "narrow sweep for Xpeak {level} m kept hitting the displacement limit"
            ))
        })?;
        cx.hand_out(&pre, li, sweep, &mut narrow)?;
    }
    let bench_time_s = cx.elapsed_s;
    cx.log.push(format!("bench time {bench_time_s:.1} s"));
    cx.obs.progress(Step::Fit, 1.0, 0.0);
    Ok(Outcome {
        pre: pre_sig,
        pre_sweep: pre_spec,
        f0_hz: pre_info.resonance_hz,
        pre_q_drive_to_x: pre_info.q_drive_to_x,
        narrow,
        bench_time_s,
        log: cx.log,
        production: None,
    })
}
