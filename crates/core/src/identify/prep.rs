//! Preparation of the main sweep: checks, band limiting, differentiation,
//! decimation, per-period harmonics, resonance and the analysed span.

use super::AnalyzeError;
use crate::dsp::{self, LowPass, PeriodHarmonics, Spectrum};
use crate::recording::{RecordingSet, Signals};

/// Harmonics tracked per period (fundamental first).
pub const N_HARM: usize = 5;

/// The main sweep, prepared once.
#[derive(Debug, Clone)]
pub struct Prepared {
    pub mass_kg: f64,
    /// Rate of the decimated signals (Hz).
    pub fs_hz: f64,
    pub lowpass: LowPass,
    /// Whole record, band-limited and decimated.
    pub x: Vec<f64>,
    pub v: Vec<f64>,
    pub a: Vec<f64>,
    pub mic: Vec<f64>,
    /// Period marks (fractional decimated samples).
    pub marks: Vec<f64>,
    /// Per-period harmonics of x and mic (same periods).
    pub px: Vec<PeriodHarmonics>,
    pub pm: Vec<PeriodHarmonics>,
    /// Index into px of the largest fundamental displacement and its
    /// sub-period position (the displacement peak, not necessarily fR).
    pub res_index: usize,
    pub res_pos: f64,
    /// False when the displacement amplitude does not peak inside the sweep.
    pub disp_peak_inside: bool,
    /// Analysed span [start, end) in decimated samples.
    pub span: (usize, usize),
    /// Noise (standard deviations) that the band-limited signals carry,
    /// from the white sensor noise estimated above the low-pass.
    pub noise_x_m: f64,
    pub noise_v_m_per_s: f64,
    pub noise_a_m_per_s2: f64,
    pub noise_mic_v: f64,
}

/// Common checks of one sweep: length, finiteness, clipping of the laser.
pub fn check_signals(s: &Signals, what: &str, min_s: f64) -> Result<(), AnalyzeError> {
    // The laser's extremes and its finiteness in one pass (one pass fewer
    // over the record than `Signals::validate` before `min_max`); when a
    // check fails, `validate` names the channel and the first bad sample.
    let (mn, mx, x_finite) = min_max_finite(&s.displacement_m);
    let n = s.displacement_m.len();
    let valid = x_finite
        && s.microphone_v.len() == n
        && s.drive_v.as_ref().is_none_or(|d| d.len() == n)
        && all_finite(&s.microphone_v)
        && s.drive_v.as_deref().is_none_or(all_finite);
    if !valid {
        s.validate(what)
            .map_err(|e| AnalyzeError::Invalid(e.to_string()))?;
    }
    if !(s.sample_rate_hz.is_finite() && s.sample_rate_hz > 0.0) {
        return Err(AnalyzeError::Invalid(format!(
            "{what}: invalid sample rate {}",
            s.sample_rate_hz
        )));
    }
    if s.duration_s() < min_s {
        return Err(AnalyzeError::Invalid(format!(
            "{what}: recording too short ({:.2} s, need at least {min_s} s)",
            s.duration_s()
        )));
    }
    let min_run = ((5e-4 * s.sample_rate_hz) as usize).max(8);
    if let Some(run) = clipped_run_within(&s.displacement_m, mn, mx, min_run) {
        return Err(AnalyzeError::Invalid(format!(
            "{what}: the laser (displacement) is clipped: {run} consecutive samples stuck at its extreme value"
        )));
    }
    if mn.abs().max(mx.abs()) == 0.0 {
        return Err(AnalyzeError::Invalid(format!(
            "{what}: the displacement channel is all zero"
        )));
    }
    Ok(())
}

/// Smallest and largest sample (four lanes, so that the pass vectorises);
/// the samples are finite where they are used.
#[cfg(test)]
fn min_max(x: &[f64]) -> (f64, f64) {
    let (mn, mx, _) = min_max_finite(x);
    (mn, mx)
}

/// The smallest and largest sample and whether every sample is finite, in
/// one pass.
fn min_max_finite(x: &[f64]) -> (f64, f64, bool) {
    let (mut lo, mut hi) = ([f64::INFINITY; 4], [f64::NEG_INFINITY; 4]);
    let mut finite = [true; 4];
    let chunks = x.chunks_exact(4);
    let rest = chunks.remainder();
    for c in chunks {
        for i in 0..4 {
            lo[i] = if c[i] < lo[i] { c[i] } else { lo[i] };
            hi[i] = if c[i] > hi[i] { c[i] } else { hi[i] };
            finite[i] &= c[i].is_finite();
        }
    }
    let fold = |a: [f64; 4], f: fn(f64, f64) -> f64, init: f64| {
        a.into_iter().chain(rest.iter().copied()).fold(init, f)
    };
    (
        fold(lo, f64::min, f64::INFINITY),
        fold(hi, f64::max, f64::NEG_INFINITY),
        finite.iter().all(|&f| f) && rest.iter().all(|v| v.is_finite()),
    )
}

/// Every sample finite ([`Signals::validate`]'s test: blocks without an
/// early exit, so that the pass vectorises).
fn all_finite(c: &[f64]) -> bool {
    c.chunks(1024)
        .all(|b| b.iter().fold(true, |ok, v| ok & v.is_finite()))
}

/// Longest run (at least `min_run`) of samples pinned at the signal's maximum
/// or minimum: a sensor at the end of its range. A real peak (noisy or
/// quantised) stays at its extreme value for a few samples at most.
#[cfg(test)]
fn clipped_run(x: &[f64], min_run: usize) -> Option<usize> {
    let (mn, mx) = min_max(x);
    clipped_run_within(x, mn, mx, min_run)
}

/// [`clipped_run`] with the extremes known: one pass for both. A block of
/// 64 samples none of which is at an extreme (nearly all of a record) only
/// ends the runs, so it is tested as a whole (a pass that vectorises) and
/// walked sample by sample only when one is.
fn clipped_run_within(x: &[f64], mn: f64, mx: f64, min_run: usize) -> Option<usize> {
    let tol = 1e-9 * (mx - mn).abs().max(f64::MIN_POSITIVE);
    let (mut lo, mut hi, mut best) = (0usize, 0usize, 0usize);
    for block in x.chunks(64) {
        let any = block.iter().fold(false, |a, &v| {
            a | ((v - mn).abs() <= tol) | ((v - mx).abs() <= tol)
        });
        if !any {
            (lo, hi) = (0, 0);
            continue;
        }
        for &v in block {
            lo = if (v - mn).abs() <= tol { lo + 1 } else { 0 };
            hi = if (v - mx).abs() <= tol { hi + 1 } else { 0 };
            best = best.max(lo).max(hi);
        }
    }
    (best >= min_run).then_some(best)
}

/// Low-pass for a record at `fs`: the suspension signals lie below ~500 Hz.
pub fn lowpass_for(fs: f64) -> LowPass {
    let stop = 1200.0f64.min(0.4 * fs);
    LowPass {
        pass_hz: 2.0 * stop / 3.0,
        stop_hz: stop,
    }
}

/// Fractional-sample period marks (in decimated samples) from the drive when
/// recorded, else from the band-limited displacement.
fn marks(main: &Signals, x: &[f64], decim: usize) -> Vec<f64> {
    if let Some(d) = &main.drive_v {
        let peak = dsp::max_abs(d);
        if peak > 0.0 {
            let m = dsp::period_marks(d, 0.05 * peak);
            if m.len() > 10 {
                return m.into_iter().map(|t| t / decim as f64).collect();
            }
        }
    }
    let mean = x.iter().sum::<f64>() / x.len().max(1) as f64;
    let centred: Vec<f64> = x.iter().map(|v| v - mean).collect();
    let peak = dsp::max_abs(&centred);
    dsp::period_marks(&centred, 0.05 * peak)
}

pub fn prepare(set: &RecordingSet) -> Result<Prepared, AnalyzeError> {
    prepare_sweep(&set.main, set.meta.moving_mass_kg, "main")
}

/// [`prepare`] for any sweep of the set (`what` names it in errors): the
/// diagnostics prepare the pre-measurement the same way for the force
/// balance of the small-signal model.
pub fn prepare_sweep(main: &Signals, mass_kg: f64, what: &str) -> Result<Prepared, AnalyzeError> {
    check_sweep(main, mass_kg, what)?;
    let (sx, sm) = spectra(main);
    prepare_spectra(main, mass_kg, what, &sx, &sm)
}

/// What every preparation of a sweep checks first: a positive finite mass
/// and usable signals.
fn check_sweep(main: &Signals, mass_kg: f64, what: &str) -> Result<(), AnalyzeError> {
    check_mass(mass_kg)?;
    check_signals(main, what, 0.5)
}

fn check_mass(mass_kg: f64) -> Result<(), AnalyzeError> {
    if !(mass_kg.is_finite() && mass_kg > 0.0) {
        return Err(AnalyzeError::Invalid(format!(
            "moving_mass_kg must be a positive number of kilograms, got {mass_kg}"
        )));
    }
    Ok(())
}

/// The spectra [`prepare_sweep`] works on (whole records, padded by at
/// least 64): the band up to the low-pass and the noise band above it.
pub fn spectra(s: &Signals) -> (Spectrum, Spectrum) {
    let fs = s.sample_rate_hz;
    band_spectra(s, lowpass_for(fs).stop_hz, Some(noise_band(fs)))
}

/// Displacement and microphone spectra of `s` (whole records, padded by at
/// least 64) up to `up_to_hz` and in the `noise` band, side by side on
/// rayon's pool.
pub(super) fn band_spectra(
    s: &Signals,
    up_to_hz: f64,
    noise: Option<(f64, f64)>,
) -> (Spectrum, Spectrum) {
    let fs = s.sample_rate_hz;
    rayon::join(
        || Spectrum::bands(&s.displacement_m, fs, 64, up_to_hz, noise),
        || Spectrum::bands(&s.microphone_v, fs, 64, up_to_hz, noise),
    )
}

/// The band (Hz) above the low-pass whose white noise sets the noise of the
/// band-limited signals.
pub(super) fn noise_band(fs: f64) -> (f64, f64) {
    let nyq = 0.5 * fs;
    ((2.0 * lowpass_for(fs).stop_hz).min(0.5 * nyq), 0.95 * nyq)
}

/// [`prepare_sweep`] on the [`spectra`] of the sweep (the diagnostics share
/// the pre-measurement's between the small-signal fit and its force
/// balance). The record was checked ([`check_signals`]) before its spectra
/// were taken, so only the mass and that the spectra are this record's
/// (its length) are checked again: the channel checks are a pass over
/// every sample.
pub fn prepare_shared(
    main: &Signals,
    mass_kg: f64,
    what: &str,
    sx: &Spectrum,
    sm: &Spectrum,
) -> Result<Prepared, AnalyzeError> {
    check_mass(mass_kg)?;
    if sx.len != main.len() || sm.len != main.len() {
        return Err(AnalyzeError::Invalid(format!(
            "{what}: the spectra are not this record's ({} samples, spectra of {} and {})",
            main.len(),
            sx.len,
            sm.len
        )));
    }
    prepare_spectra(main, mass_kg, what, sx, sm)
}

fn prepare_spectra(
    main: &Signals,
    mass_kg: f64,
    what: &str,
    sx: &Spectrum,
    sm: &Spectrum,
) -> Result<Prepared, AnalyzeError> {
    let fs = main.sample_rate_hz;
    let lowpass = lowpass_for(fs);
    let (decim, x, v, a, mic) = dsp::spectrum::with_thread_planner(|planner| {
        let decim = sx.max_decimation(lowpass.stop_hz);
        let x = sx.derivative(lowpass, 0, decim, planner);
        let v = sx.derivative(lowpass, 1, decim, planner);
        let a = sx.derivative(lowpass, 2, decim, planner);
        let mic = sm.derivative(lowpass, 0, decim, planner);
        (decim, x, v, a, mic)
    });
    let fs_d = fs / decim as f64;

    let mk = marks(main, &x, decim);
    let (px, pm) = {
        let mut both = dsp::harmonics_per_period_of(&[&x, &mic], &mk, fs_d, N_HARM);
        let pm = both.pop().unwrap_or_default();
        (both.pop().unwrap_or_default(), pm)
    };
    if px.len() < 20 {
        return Err(AnalyzeError::Invalid(format!(
            "{what}: too few oscillation periods found ({}): not a sweep, or too short",
            px.len()
        )));
    }
    // Resonance: the maximum of the fundamental displacement amplitude along the sweep.
    let amp: Vec<f64> = px.iter().map(|p| p.amplitude(1)).collect();
    // A displacement that does not peak inside the sweep is no error yet: on
    // large cones the resonance shows in the phase of X/F, not in |X| (the
    // analysis decides, see `large::find`).
    let peak = dsp::resonance_peak(&amp, 2, 0.1);
    let (res_index, res_pos) = peak.unwrap_or_else(|| {
        let i = amp
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map_or(0, |(i, _)| i);
        (i, i as f64)
    });
    // Analysed span: the periods whose fundamental exceeds 10 % of the peak.
    let thr = 0.1 * amp[res_index];
    let first = amp.iter().position(|&a| a >= thr).unwrap_or(0);
    let last = amp.iter().rposition(|&a| a >= thr).unwrap_or(amp.len() - 1);
    let s0 = px[first].start.ceil().max(0.0) as usize;
    let s1 = (px[last].end.floor() as usize).min(x.len());

    // Noise from the band above the low-pass (white noise assumed).
    let (lo, hi) = noise_band(fs);
    let laser_noise_m = sx.white_noise_std(lo, hi).unwrap_or(0.0);
    let mic_noise_v = sm.white_noise_std(lo, hi).unwrap_or(0.0);
    Ok(Prepared {
        mass_kg,
        fs_hz: fs_d,
        lowpass,
        noise_x_m: sx.filtered_noise_std(laser_noise_m, lowpass, 0),
        noise_v_m_per_s: sx.filtered_noise_std(laser_noise_m, lowpass, 1),
        noise_a_m_per_s2: sx.filtered_noise_std(laser_noise_m, lowpass, 2),
        noise_mic_v: sm.filtered_noise_std(mic_noise_v, lowpass, 0),
        x,
        v,
        a,
        mic,
        px,
        pm,
        marks: mk,
        res_index,
        res_pos,
        disp_peak_inside: peak.is_some(),
        span: (s0, s1),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipping_is_found_noise_is_not() {
        let mut x: Vec<f64> = (0..1000).map(|i| (i as f64 * 0.05).sin()).collect();
        assert_eq!(clipped_run(&x, 8), None);
        for v in x.iter_mut() {
            *v = v.clamp(-0.9, 0.9);
        }
        assert!(clipped_run(&x, 8).unwrap() >= 8);
    }

    /// The fused pass finds what `Signals::validate` finds, with its
    /// message: a non-finite sample in any channel (named, with its index),
    /// channels of different lengths; and the laser's extremes.
    #[test]
    fn checks_name_what_validate_names() {
        let n = 48_000;
        let s = Signals {
            sample_rate_hz: 48_000.0,
            displacement_m: (0..n).map(|i| 1e-3 * (i as f64 * 0.01).sin()).collect(),
            microphone_v: (0..n).map(|i| 0.1 * (i as f64 * 0.02).cos()).collect(),
            drive_v: Some((0..n).map(|i| (i as f64 * 0.03).sin()).collect()),
        };
        assert!(check_signals(&s, "main", 0.5).is_ok());
        let x = &s.displacement_m[..1003]; // lanes and a remainder
        let folded = (
            x.iter().copied().fold(f64::INFINITY, f64::min),
            x.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            true,
        );
        assert_eq!(min_max_finite(x), folded);
        assert!(!min_max_finite(&[1.0, 2.0, 3.0, 4.0, f64::NAN]).2);
        type Spoil = fn(&mut Signals);
        let bad: [(&str, Spoil); 5] = [
            ("displacement", |s| s.displacement_m[40_001] = f64::NAN),
            ("displacement", |s| s.displacement_m[47_999] = f64::INFINITY),
            ("microphone", |s| s.microphone_v[7] = f64::NAN),
            ("drive", |s| {
                s.drive_v.as_mut().unwrap()[123] = f64::NEG_INFINITY
            }),
            ("different lengths", |s| {
                s.microphone_v.pop();
            }),
        ];
        for (name, spoil) in bad {
            let mut t = s.clone();
            spoil(&mut t);
            let e = check_signals(&t, "main", 0.5).unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
            assert_eq!(e, t.validate("main").unwrap_err().to_string());
        }
    }

    /// The run's length is counted across the 64-sample blocks, and a
    /// block without an extreme ends it.
    #[test]
    fn clipped_runs_are_counted_across_blocks() {
        let mut x: Vec<f64> = (0..1000).map(|i| 0.5 * (i as f64 * 0.05).sin()).collect();
        x[60..75].fill(1.0); // 15 samples over a block boundary (64)
        x[300..310].fill(-1.0);
        assert_eq!(clipped_run(&x, 8), Some(15));
        x[200..203].fill(1.0);
        x[260..262].fill(1.0); // another block between: no longer run
        assert_eq!(clipped_run(&x, 16), None);
    }
}
