//! Break-in (paper §7, issue 32): a time at the part's resonance at a level
//! before the measurement, so that repeated measurements do not drift. A
//! short low-level sweep finds the resonance; then a sine is held in chunks,
//! each retuned to the resonance (the fundamental of x lags the box pressure
//! by 90 degrees there; the resonance moves with the level and as the part
//! softens) and its drive set for the target peak displacement. Runs on any
//! [`Bench`], within its limits.

use super::run::{analyse, MAX_SEARCH, SEARCH_S, SEARCH_TOL, SHORT_SILENCE_S};
use super::{ProcedureConfig, ProcedureError, SweepSpec};
use crate::{Bench, Block, Control};
use serde::{Deserialize, Serialize};

/// The break-in a job or recipe asks for.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BreakIn {
    /// Time at resonance (s); the paper's 5 minutes by default.
    #[serde(default = "default_duration")]
    pub duration_s: f64,
    /// Peak displacement to hold (m).
    pub xpeak_m: f64,
}

fn default_duration() -> f64 {
    300.0
}

/// The seed's default: 5 minutes.
pub const DEFAULT_DURATION_S: f64 = 300.0;

impl BreakIn {
    pub fn validate(&self, max_displacement_m: f64) -> Result<(), String> {
        if !(self.duration_s.is_finite() && (1.0..=7200.0).contains(&self.duration_s)) {
            return Err(format!(
                "break_in.duration_s must be 1..7200 s, got {}",
                self.duration_s
            ));
        }
        if !(self.xpeak_m.is_finite() && self.xpeak_m > 0.0 && self.xpeak_m < max_displacement_m) {
            return Err(format!(
                "break_in.xpeak_m must be > 0 and below the bench's limit {max_displacement_m} m, got {}",
                self.xpeak_m
            ));
        }
        Ok(())
    }
}

/// The break-in that was done (stated in the result).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BreakInDone {
    /// What was asked.
    pub target_duration_s: f64,
    pub target_xpeak_m: f64,
    /// Time the sine was held (faded parts excluded, s).
    pub held_s: f64,
    /// Mean peak displacement over the held time (m).
    pub xpeak_m: f64,
    /// Frequency of the last chunk (the resonance at the level, Hz) and its drive (V).
    pub f_hz: f64,
    pub drive_v: f64,
    /// Bench time including the resonance search (s).
    pub bench_time_s: f64,
}

/// Length of one held chunk (s) and its fades (the loop's hold,
/// `waveform::hold_loop`, plays the same chunks).
pub(super) const CHUNK_S: f64 = 10.0;
pub(super) const FADE_S: f64 = 0.25;
/// Each chunk glides up from this fraction of its frequency over `RAMP_S`.
const GLIDE_FROM: f64 = 0.7;
const RAMP_S: f64 = 1.5;
/// The phase lag of x behind the force held (75 degrees): just below the
/// top of a hardening part's upper branch, where the response would jump
/// down at the next step (at 90 degrees one chunk in three jumped).
const HOLD_LAG_RAD: f64 = 75.0 * std::f64::consts::PI / 180.0;

/// Fundamental of `x` at `f_hz` over samples `from..` (complex amplitude).
fn fundamental(x: &[f64], fs: f64, f_hz: f64, from: usize, to: usize) -> (f64, f64) {
    let w = 2.0 * std::f64::consts::PI * f_hz / fs;
    let (mut re, mut im) = (0.0, 0.0);
    for (k, v) in x.iter().enumerate().take(to).skip(from) {
        let a = w * k as f64;
        re += v * a.cos();
        im -= v * a.sin();
    }
    let n = (to - from).max(1) as f64;
    (2.0 * re / n, 2.0 * im / n)
}

/// Runs the break-in on `bench`; the caller measures afterwards.
pub fn break_in(
    bench: &mut dyn Bench,
    cfg: &ProcedureConfig,
    b: &BreakIn,
    cancelled: &mut dyn FnMut() -> bool,
) -> Result<BreakInDone, ProcedureError> {
    hold_at_resonance(bench, cfg, b, cancelled, &mut || false, &mut |_| {})
}

/// The break-in's sine held at the resonance at a level, with every run's
/// signals handed to `on_run` as it finishes (the probe, the search sweeps,
/// each held chunk): the long-term test's stimulus on a hardware or
/// emulated bench measures the load it puts on the part from them.
/// `stop` ends the hold early but gracefully, at the end of a chunk (each
/// fades out to silence): the long-term test's pause by the user; the
/// answer then says the time held so far.
pub fn hold_at_resonance(
    bench: &mut dyn Bench,
    cfg: &ProcedureConfig,
    b: &BreakIn,
    cancelled: &mut dyn FnMut() -> bool,
    stop: &mut dyn FnMut() -> bool,
    on_run: &mut dyn FnMut(&crate::Signals),
) -> Result<BreakInDone, ProcedureError> {
    let limits = bench.limits();
    b.validate(limits.max_displacement_m)
        .map_err(ProcedureError::Invalid)?;
    let fs = bench.sample_rate_hz();
    let limit = limits.max_displacement_m;
    let mut bench_time = 0.0;
    // Resonance and gain from a short low-level sweep (raised until the part moves).
    let mut v = 0.5f64.min(limits.max_drive_v);
    let mut found = None;
    for _ in 0..4 {
        let mut spec = SweepSpec::new(cfg.pre_f_start_hz, cfg.pre_f_end_hz, 2.0, v);
        spec.silence_s = 0.2;
        let Some(sig) = play_guarded(bench, &spec, limit, &mut bench_time, on_run)? else {
            v /= 10.0;
            continue;
        };
        let info = analyse(&spec, &sig)
            .ok_or_else(|| ProcedureError::Failed("break-in probe too short".into()))?;
        if info.x_fund_peak_m < 0.03 * b.xpeak_m && v < limits.max_drive_v {
            v = (v * 10.0).min(limits.max_drive_v);
            continue;
        }
        found = Some(info);
        break;
    }
    let info = found.ok_or_else(|| {
        ProcedureError::Failed("break-in: the probe found no resonance within the limits".into())
    })?;
    let mut f = info.resonance_hz;
    let mut v = (b.xpeak_m / info.gain_m_per_v.max(1e-12)).min(limits.max_drive_v);
    // The resonance at the level: a hardening part's resonance rises with
    // the excursion (spider_3in: 38.7 Hz at the probe's level, 59.6 Hz at
    // 9 mm), and the held chunks climb to it by at most `step` per chunk:
    // started at the probe's resonance they spent the first 110 s of a 5-min
    // break-in below the level (mean 7.9 mm of 9 mm, 6.5 kJ of load instead
    // of the 10.9 kJ of 5 min at 9 mm). The measurement's resonance search
    // (rising sweeps of one octave at the level's drive) finds it first.
    let mut last_xpk = 0.0f64;
    for _ in 0..MAX_SEARCH {
        if cancelled() {
            return Err(ProcedureError::Cancelled);
        }
        let mut spec = SweepSpec::new(
            f * 2f64.powf(-1.0 / 3.0),
            f * 2f64.powf(2.0 / 3.0),
            SEARCH_S,
            v,
        );
        spec.silence_s = SHORT_SILENCE_S;
        let Some(sig) = play_guarded(bench, &spec, limit, &mut bench_time, on_run)? else {
            v *= 0.5;
            continue;
        };
        let Some(s) = analyse(&spec, &sig) else {
            continue;
        };
        f = s.resonance_hz;
        last_xpk = s.xpeak_m;
        let ratio = b.xpeak_m / s.xpeak_m.max(1e-9);
        if (ratio - 1.0).abs() < SEARCH_TOL {
            break;
        }
        let nv = (v * ratio.clamp(0.33, 3.0)).min(limits.max_drive_v);
        if nv == v {
            break;
        }
        v = nv;
    }
    let mut step = 0.04;
    // A held sine falls off a hardening part's upper branch below the
    // frequency a rising sweep jumps at: the hold starts one retuning step
    // below the search's resonance and climbs from there.
    f *= 1.0 - step;
    let mut last_dir = 0.0f64;
    let (mut held, mut x_sum) = (0.0, 0.0);
    let mut drive_used = v;
    while held < b.duration_s - 1e-9 {
        if cancelled() {
            return Err(ProcedureError::Cancelled);
        }
        if stop() {
            break;
        }
        let hold = (b.duration_s - held).clamp(0.5, CHUNK_S - 2.0 * FADE_S);
        let len_s = hold + 2.0 * FADE_S;
        let n = (len_s * fs).round() as usize;
        let nf = (FADE_S * fs).round() as usize;
        // Each chunk starts from rest: a short rising glide into the
        // frequency keeps a hardening part on the upper branch of its
        // resonance (as the procedure's rising sweeps do).
        let nr = ((RAMP_S * fs).round() as usize).min(n / 2);
        let mut phase = 0.0f64;
        let drive: Vec<f64> = (0..n)
            .map(|k| {
                let g = chunk_fade(k, n, nf);
                let fk = if k < nr {
                    f * (GLIDE_FROM + (1.0 - GLIDE_FROM) * k as f64 / nr as f64)
                } else {
                    f
                };
                let u = g * v * phase.sin();
                phase += 2.0 * std::f64::consts::PI * fk / fs;
                u
            })
            .collect();
        let played = play_chunk(bench, &drive, limit, cancelled);
        bench_time += len_s;
        let Some(sig) = played? else {
            v *= 0.7;
            continue;
        };
        on_run(&sig);
        // The steady second half of the held part.
        let (from, to) = (nf + (n - 2 * nf) / 2, n - nf);
        let x = &sig.displacement_m;
        let xpk = x[from..to].iter().fold(0.0f64, |a, v| a.max(v.abs()));
        held += hold;
        x_sum += xpk * hold;
        drive_used = v;
        // Retune: x lags the force (the box pressure) by 90 degrees at
        // resonance; hold just below it.
        let (xr, xi) = fundamental(x, fs, f, from, to);
        let (mr, mi) = fundamental(&sig.microphone_v, fs, f, from, to);
        let lag = (mi.atan2(mr) - xi.atan2(xr)).rem_euclid(2.0 * std::f64::consts::PI);
        let jumped = xpk < 0.3 * last_xpk;
        if jumped {
            // Past the top of the upper branch: the response jumped down.
            // Back off below it and climb more slowly.
            f *= 1.0 - 2.0 * step;
            step = (step * 0.5f64).max(0.002);
            last_dir = 1.0;
        } else {
            let dir = if lag < HOLD_LAG_RAD { 1.0 } else { -1.0 };
            if last_dir != 0.0 && dir != last_dir {
                step = (step * 0.5f64).max(0.002);
            }
            last_dir = dir;
            f *= 1.0 + dir * step;
            last_xpk = xpk;
        }
        if xpk > 0.0 && !jumped {
            v = (v * (b.xpeak_m / xpk).clamp(0.5, 2.0)).min(limits.max_drive_v);
        }
    }
    Ok(BreakInDone {
        target_duration_s: b.duration_s,
        target_xpeak_m: b.xpeak_m,
        held_s: held,
        xpeak_m: if held > 0.0 { x_sum / held } else { 0.0 },
        f_hz: f,
        drive_v: drive_used,
        bench_time_s: bench_time,
    })
}

/// The weight of sample `k` of an `n`-sample chunk: a raised-cosine fade
/// over its first and last `nf` samples, 1 between.
pub(super) fn chunk_fade(k: usize, n: usize, nf: usize) -> f64 {
    if k < nf {
        0.5 * (1.0 - (std::f64::consts::PI * k as f64 / nf as f64).cos())
    } else if k + nf > n {
        0.5 * (1.0 - (std::f64::consts::PI * (n - k) as f64 / nf as f64).cos())
    } else {
        1.0
    }
}

/// Plays one held chunk, stopped as soon as |x| passes `limit` (Ok(None):
/// the bench ramped down, the caller lowers the level and plays again) or
/// the test is cancelled (Err(Cancelled)).
pub(super) fn play_chunk(
    bench: &mut dyn Bench,
    drive: &[f64],
    limit: f64,
    cancelled: &mut dyn FnMut() -> bool,
) -> Result<Option<crate::Signals>, ProcedureError> {
    let mut hit = false;
    let sig = bench.run(drive, &mut |blk: Block<'_>| {
        if blk.displacement_m.iter().any(|x| x.abs() > limit) {
            hit = true;
            return Control::Abort;
        }
        if cancelled() {
            return Control::Abort;
        }
        Control::Continue
    });
    if hit {
        return Ok(None);
    }
    match sig {
        Err(crate::BenchError::Aborted) => Err(ProcedureError::Cancelled),
        r => Ok(Some(r?)),
    }
}

/// Plays a probe or search sweep, stopped as soon as |x| passes `limit`:
/// None when it did (the caller lowers the drive and plays again); the
/// sweep's length is added to `bench_time` either way.
fn play_guarded(
    bench: &mut dyn Bench,
    spec: &SweepSpec,
    limit: f64,
    bench_time: &mut f64,
    on_run: &mut dyn FnMut(&crate::Signals),
) -> Result<Option<crate::Signals>, ProcedureError> {
    let fs = bench.sample_rate_hz();
    let drive = spec.samples(fs);
    *bench_time += drive.len() as f64 / fs;
    let mut hit = false;
    let sig = bench.run(&drive, &mut |blk: Block<'_>| {
        if blk.displacement_m.iter().any(|x| x.abs() > limit) {
            hit = true;
            return Control::Abort;
        }
        Control::Continue
    });
    if hit {
        return Ok(None);
    }
    let sig = sig?;
    on_run(&sig);
    Ok(Some(sig))
}
