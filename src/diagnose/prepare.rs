//! Fallback preparation of the force-balance data from a recording set, used
//! only while `identify::force_balance_data` is unavailable (it returns an
//! error): band-limited differentiation with `dsp::Spectrum`, decimation,
//! and the analysed span where the sweep drives the part.

use crate::dsp::{LowPass, Spectrum};
use crate::identify::ForceBalanceData;
use crate::recording::RecordingSet;
use realfft::RealFftPlanner;

/// Force-balance data of the main sweep of `set`.
pub fn force_balance_from_set(set: &RecordingSet) -> Result<ForceBalanceData, String> {
    let s = &set.main;
    s.validate("main").map_err(|e| e.to_string())?;
    let fs = s.sample_rate_hz;
    let n = s.len();
    if n < (fs * 0.5) as usize {
        return Err(format!("main recording too short: {n} samples"));
    }
    let mut planner = RealFftPlanner::<f64>::new();
    let xs = Spectrum::with_planner(&s.displacement_m, fs, n / 8, &mut planner);
    let ms = Spectrum::with_planner(&s.microphone_v, fs, n / 8, &mut planner);
    // Highest fundamental: the top of the band holding 99 % of x's energy above 2 Hz.
    let k_lo = (2.0 / xs.df_hz()).ceil() as usize;
    let power: Vec<f64> = xs.bins.iter().map(|c| c.norm_sqr()).collect();
    let total: f64 = power[k_lo..].iter().sum();
    if total <= 0.0 {
        return Err("main recording: the part does not move".into());
    }
    let mut acc = 0.0;
    let mut k99 = power.len() - 1;
    for (k, p) in power.iter().enumerate().skip(k_lo) {
        acc += p;
        if acc >= 0.99 * total {
            k99 = k;
            break;
        }
    }
    let f_fund = xs.freq_hz(k99);
    let pass = (12.0 * f_fund).min(0.3 * fs);
    let lp = LowPass {
        pass_hz: pass,
        stop_hz: 1.3 * pass,
    };
    let decim = xs.max_decimation(lp.stop_hz);
    let x = xs.derivative(lp, 0, decim, &mut planner);
    let v = xs.derivative(lp, 1, decim, &mut planner);
    let a = xs.derivative(lp, 2, decim, &mut planner);
    let mic = ms.derivative(lp, 0, decim, &mut planner);
    let fsd = fs / decim as f64;
    // Analysed span: where the running peak of |x| exceeds 30 % of the
    // maximum, trimmed by 50 ms at both ends (record edges, fades).
    let w = ((0.05 * fsd) as usize).max(1);
    let xmax = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let env: Vec<f64> = (0..x.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(w), (i + w + 1).min(x.len()));
            x[a..b].iter().fold(0.0f64, |m, v| m.max(v.abs()))
        })
        .collect();
    let first = env.iter().position(|&e| e > 0.3 * xmax).unwrap_or(0) + w;
    let last = env
        .iter()
        .rposition(|&e| e > 0.3 * xmax)
        .unwrap_or(x.len() - 1);
    let last = last.saturating_sub(w);
    if last <= first + 400 {
        return Err("main recording: too little large-signal motion to analyse".into());
    }
    let noise_band = (lp.stop_hz * 1.1, 0.45 * fs);
    Ok(ForceBalanceData {
        sample_rate_hz: fsd,
        t0_s: first as f64 / fsd,
        mass_kg: set.meta.moving_mass_kg,
        x_m: x[first..last].to_vec(),
        v_m_per_s: v[first..last].to_vec(),
        a_m_per_s2: a[first..last].to_vec(),
        mic_v: mic[first..last].to_vec(),
        laser_noise_m: xs
            .white_noise_std(noise_band.0, noise_band.1)
            .unwrap_or(0.0),
        mic_noise_v: ms
            .white_noise_std(noise_band.0, noise_band.1)
            .unwrap_or(0.0),
    })
}
