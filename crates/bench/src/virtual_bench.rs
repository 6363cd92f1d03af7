//! [`VirtualBench`]: the lumped model behind the [`Bench`] trait, streaming
//! block by block like an audio device, with the sensors' noise, range,
//! quantisation, delays and ADC clipping.

use crate::{Bench, BenchError, Block, Control, Limits};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use springbench_core::physics::ageing::AgeingStep;
use springbench_core::physics::model::{idx, BenchParams, Integrator, Model};
use springbench_core::physics::PartSpec;
use springbench_core::recording::{ChannelScale, Signals};
use springbench_recording::codec::Resolution;

/// Samples per block handed to the observer (10 ms at 48 kHz).
pub const BLOCK_LEN: usize = 480;
/// Length of the ramp-down after an abort (s).
pub const ABORT_RAMP_S: f64 = 0.01;

/// The virtual bench: implements [`crate::Bench`].
pub struct VirtualBench {
    pub part: PartSpec,
    pub seed: u64,
    /// Exciter, box and sensors.
    pub bench: BenchParams,
    /// Hard limits reported to the procedure.
    pub limits: Limits,
    /// Stable identifier.
    pub id: String,
    /// Relative error of the laser's sensitivity: it reads (1 + error) x
    /// (`[benches.virtual] laser_gain_error`).
    pub laser_gain_error: f64,
    /// Sweeps played so far (each gets its own noise).
    runs: u64,
    /// The load the mounted part has taken (J, `physics::ageing`) when this
    /// bench ages it; None: the part stays as it is (the default: one
    /// measurement of a new part).
    ageing_load_j: Option<f64>,
}

/// The accelerated sine's excursion is found again this often (s of test
/// time) while the drive limit holds it short.
pub const SINE_REACH_STEP_S: f64 = 60.0;

/// An accelerated sine as applied ([`VirtualBench::apply_sine_load`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SineApplied {
    /// The load added (J).
    pub load_j: f64,
    /// The peak excursion reached at its start (m): its target, or less
    /// where the drive limit holds it short.
    pub reach_m: f64,
}

/// Default limits of the virtual bench: the exciter's +-20 mm are the part's too.
pub const DEFAULT_LIMITS: Limits = Limits {
    max_displacement_m: 0.02,
    max_drive_v: 100.0,
};

impl VirtualBench {
    pub fn new(part: PartSpec, seed: u64) -> VirtualBench {
        VirtualBench {
            part,
            seed,
            bench: BenchParams::default(),
            limits: DEFAULT_LIMITS,
            id: "virtual-0".into(),
            laser_gain_error: 0.0,
            runs: 0,
            ageing_load_j: None,
        }
    }

    /// Ages the mounted part (its `ageing` parameters) from the load
    /// `load_j` it has taken before (0: a new part): every sweep adds its
    /// load, K(x) near rest falls with it, and the state carries over from
    /// one sweep and one measurement to the next.
    pub fn with_ageing(mut self, load_j: f64) -> VirtualBench {
        self.ageing_load_j = Some(load_j.max(0.0));
        self
    }

    /// The load the part has taken (J); None when this bench does not age it.
    pub fn ageing_load_j(&self) -> Option<f64> {
        self.ageing_load_j
    }

    /// The part's stiffness at rest now (N/m): k0 less what ageing removed.
    pub fn k0_now_n_per_m(&self) -> f64 {
        let k0 = self.part.k_coeffs_si[0];
        match (&self.part.ageing, self.ageing_load_j) {
            (Some(a), Some(e)) => a.k0_n_per_m(k0, e),
            _ => k0,
        }
    }

    /// The peak excursion this bench's sine at the part's resonance holds
    /// now for a target `xpeak_m`: the target, or less where the drive limit
    /// holds it short (`physics::ageing::sine_reach_m`).
    pub fn sine_reach_m(&self, xpeak_m: f64) -> f64 {
        springbench_core::physics::ageing::sine_reach_m(
            &self.part,
            &self.bench,
            self.limits.max_drive_v,
            self.ageing_load_j.unwrap_or(0.0),
            xpeak_m,
        )
    }

    /// Accelerated load: `duration_s` of a sine held at the part's current
    /// resonance at `xpeak_m`, applied analytically (`physics::ageing::apply_sine`)
    /// instead of simulated sample by sample, within the drive limit: where
    /// it holds the sine short, at the excursion reached
    /// ([`Self::sine_reach_m`], again every [`SINE_REACH_STEP_S`] as the part
    /// changes). The load added (0 when this bench does not age the part)
    /// and the excursion reached at the start.
    pub fn apply_sine_load(&mut self, xpeak_m: f64, duration_s: f64) -> SineApplied {
        let mut reach = self.sine_reach_m(xpeak_m);
        let Some(e0) = self.ageing_load_j else {
            return SineApplied {
                load_j: 0.0,
                reach_m: reach,
            };
        };
        let reach_m = reach;
        let mut left = duration_s.max(0.0);
        let mut e = e0;
        loop {
            // Reached: a softening part needs less drive as it goes on.
            let span = if reach >= xpeak_m {
                left
            } else {
                left.min(SINE_REACH_STEP_S)
            };
            e = springbench_core::physics::ageing::apply_sine(&self.part, e, reach, span);
            self.ageing_load_j = Some(e);
            left -= span;
            if left <= 0.0 {
                break;
            }
            reach = self.sine_reach_m(xpeak_m);
        }
        SineApplied {
            load_j: e - e0,
            reach_m,
        }
    }

    /// As [`Self::apply_sine_load`], the sine held at a drive level: its
    /// velocity amplitude at the resonance, `velocity_m_per_s`
    /// (`physics::ageing::apply_sine_at_velocity`). Returns the load added (J).
    pub fn apply_sine_load_at_velocity(&mut self, velocity_m_per_s: f64, duration_s: f64) -> f64 {
        let Some(e0) = self.ageing_load_j else {
            return 0.0;
        };
        let e1 = springbench_core::physics::ageing::apply_sine_at_velocity(
            &self.part,
            e0,
            velocity_m_per_s,
            duration_s,
        );
        self.ageing_load_j = Some(e1);
        e1 - e0
    }

    /// Accelerated load of a drive loop held at an RMS displacement
    /// `x_rms_m` for `duration_s` (band-limited noise, decision 0137): the
    /// loop's load rate on the part as it is, re-evaluated as it ages
    /// (`physics::waveform::LoopLoad`), within the bench's drive limit.
    /// Returns the load added (J); 0 when this bench does not age the part.
    pub fn apply_loop_load(
        &mut self,
        stimulus: &mut springbench_core::physics::waveform::LoopLoad,
        x_rms_m: f64,
        duration_s: f64,
    ) -> f64 {
        let Some(e0) = self.ageing_load_j else {
            return 0.0;
        };
        let e1 = stimulus.apply(
            &self.part,
            &self.bench,
            self.limits.max_drive_v,
            e0,
            x_rms_m,
            duration_s,
        );
        self.ageing_load_j = Some(e1);
        e1 - e0
    }

    /// This bench's differences from its neighbours (`[benches.virtual]`):
    /// the laser's sensitivity error, the inner clamp's extra mass (added
    /// to the mounted part's moving mass), the effects it adds to every
    /// part. Pacing is the caller's ([`crate::procedure::pace::Paced`]).
    pub fn with_config(mut self, cfg: &crate::settings::VirtualConfig) -> VirtualBench {
        self.laser_gain_error = cfg.laser_gain_error;
        self.part.moving_mass_kg += cfg.clamp_mass_kg;
        self.part.effects = self.part.effects.overlaid_with(&cfg.part_effects);
        self
    }

    pub fn with_bench(mut self, bench: BenchParams) -> VirtualBench {
        self.bench = bench;
        self
    }

    pub fn with_limits(mut self, limits: Limits) -> VirtualBench {
        self.limits = limits;
        self
    }

    /// Number of sweeps played.
    pub fn runs(&self) -> u64 {
        self.runs
    }
}

/// The converter of a virtual bench: `converter_bits` over the laser's
/// range and the ADC's full scale.
pub fn converter_resolution(b: &BenchParams) -> Resolution {
    Resolution {
        bits: b.converter_bits,
        scale: ChannelScale {
            displacement: Some(b.laser.range_m),
            microphone: Some(b.adc_full_scale_v),
            drive: Some(b.adc_full_scale_v),
        },
    }
}

/// Value of `hist` at fractional index `pos` (zero before the start).
#[inline]
fn delayed(hist: &[f64], k: usize, delay_samples: f64) -> f64 {
    if delay_samples == 0.0 {
        return hist[k];
    }
    let pos = k as f64 - delay_samples;
    if pos < 0.0 {
        return 0.0;
    }
    let i = pos.floor() as usize;
    let a = pos - i as f64;
    let h0 = hist[i];
    if a == 0.0 || i + 1 >= hist.len() {
        h0
    } else {
        h0 + a * (hist[i + 1] - h0)
    }
}

/// Noiseless states sampled at the sample instants: (x, p) per sample.
/// Plain offline integration without sensors (tests, comparisons).
pub fn integrate(part: &PartSpec, bench: &BenchParams, drive_v: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut sim = Integrator::new(
        Model::new(part, bench),
        bench.sample_rate_hz,
        bench.substeps,
    );
    let n = drive_v.len();
    let mut xs = Vec::with_capacity(n);
    let mut ps = Vec::with_capacity(n);
    for k in 0..n {
        xs.push(sim.state[idx::X]);
        ps.push(sim.state[idx::P]);
        let u1 = if k + 1 < n { drive_v[k + 1] } else { 0.0 };
        sim.step(drive_v[k], u1);
    }
    (xs, ps)
}

impl Bench for VirtualBench {
    fn id(&self) -> &str {
        &self.id
    }

    fn sample_rate_hz(&self) -> f64 {
        self.bench.sample_rate_hz
    }

    fn limits(&self) -> Limits {
        self.limits
    }

    fn resolution(&self) -> Option<Resolution> {
        Some(converter_resolution(&self.bench))
    }

    fn describe(&self) -> String {
        format!(
            "virtual bench (lumped model, RK4 at {} Hz) with part '{}'",
            self.bench.sample_rate_hz, self.part.name
        )
    }

    fn run(
        &mut self,
        drive_v: &[f64],
        observer: &mut dyn FnMut(Block<'_>) -> Control,
    ) -> Result<Signals, BenchError> {
        self.part.validate().map_err(BenchError::Device)?;
        self.bench.validate().map_err(BenchError::Device)?;
        let b = self.bench;
        // A dark or glossy part surface scatters less light: more laser noise.
        let laser_noise_m = self
            .part
            .laser_noise_m
            .map_or(b.laser.noise_m, |n| n.max(b.laser.noise_m));
        let fs = b.sample_rate_hz;
        let n = drive_v.len();
        if let Some(i) = drive_v.iter().position(|u| !u.is_finite()) {
            return Err(BenchError::Device(format!(
                "drive sample {i} is not finite"
            )));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.seed
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(self.runs),
        );
        self.runs += 1;
        let mut sim = Integrator::new(Model::new(&self.part, &b), fs, b.substeps);
        // Ageing: the loss at the load so far, updated every block of
        // `AgeingStep::UPDATE_SAMPLES` (the emulator ages its part the same way).
        let mut ageing = self
            .part
            .ageing
            .zip(self.ageing_load_j)
            .map(|(a, e)| AgeingStep::start(Some(a), e, &mut sim.model));
        let mic_delay = b.microphone.delay_s
            + self
                .part
                .effects
                .channel_delay
                .map(|c| c.delay_s)
                .unwrap_or(0.0);
        let laser_delay_samples = b.laser.delay_s * fs;
        let mic_delay_samples = mic_delay * fs;
        let mut x_true = Vec::with_capacity(n);
        let mut p_true = Vec::with_capacity(n);
        let mut xs = Vec::with_capacity(n);
        let mut mics = Vec::with_capacity(n);
        let mut drv = Vec::with_capacity(n);
        let ramp_len = ((ABORT_RAMP_S * fs).round() as usize).max(1);
        // Sample where the ramp-down started, and why.
        let mut abort: Option<(usize, BenchError)> = None;
        let gain_at = |k: usize, abort: &Option<(usize, BenchError)>| -> f64 {
            match abort {
                None => 1.0,
                Some((k0, _)) => {
                    let j = k.saturating_sub(*k0) as f64 / ramp_len as f64;
                    if j >= 1.0 {
                        0.0
                    } else {
                        0.5 * (1.0 + (std::f64::consts::PI * j).cos())
                    }
                }
            }
        };
        // The converter: every captured sample is one of its codes (rounded, clipped).
        let res = converter_resolution(&b);
        let adc = |fs: Option<f64>, v: f64| Resolution::quantise(res.bits, fs.unwrap_or(1.0), v);
        let mut block_start = 0;
        for k in 0..n {
            let u = drive_v[k] * gain_at(k, &abort);
            x_true.push(sim.state[idx::X]);
            p_true.push(sim.state[idx::P]);
            // Laser.
            let xm = delayed(&x_true, k, laser_delay_samples);
            if xm.abs() > b.laser.range_m && abort.is_none() {
                abort = Some((k, BenchError::LaserOutOfRange { t_s: k as f64 / fs }));
            }
            let mut xo = (1.0 + self.laser_gain_error) * xm
                + laser_noise_m * rng.sample::<f64, _>(StandardNormal);
            if b.laser.quantisation_m > 0.0 {
                xo = (xo / b.laser.quantisation_m).round() * b.laser.quantisation_m;
            }
            xs.push(adc(res.scale.displacement, xo));
            // Microphone.
            let pm = delayed(&p_true, k, mic_delay_samples)
                + b.microphone.noise_pa * rng.sample::<f64, _>(StandardNormal);
            mics.push(adc(res.scale.microphone, b.microphone.gain_v_per_pa * pm));
            drv.push(adc(res.scale.drive, u));
            let u1 = if k + 1 < n {
                drive_v[k + 1] * gain_at(k + 1, &abort)
            } else {
                0.0
            };
            sim.step(u, u1);
            if let Some(a) = ageing.as_mut() {
                // E += |F_el v| dt (the load measure, `physics::ageing`).
                a.after_step(&mut sim, fs);
            }
            let end = k + 1;
            if end - block_start == BLOCK_LEN || end == n {
                let ctl = observer(Block {
                    start_sample: block_start,
                    displacement_m: &xs[block_start..end],
                    microphone_v: &mics[block_start..end],
                    drive_v: &drv[block_start..end],
                });
                if ctl == Control::Abort && abort.is_none() {
                    abort = Some((end, BenchError::Aborted));
                }
                block_start = end;
            }
            if let Some((k0, _)) = &abort {
                if end >= k0 + ramp_len {
                    break;
                }
            }
        }
        if let Some(a) = ageing {
            self.ageing_load_j = Some(a.load_j());
        }
        if let Some((_, e)) = abort {
            return Err(e);
        }
        Ok(Signals {
            sample_rate_hz: fs,
            displacement_m: xs,
            microphone_v: mics,
            drive_v: Some(drv),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::VirtualConfig;

    /// The accelerated sine within the drive limit: on a part 400 times
    /// stiffer than spider_3in the 5.3 mm sine is held at the excursion
    /// 100 V reaches, and the load added is that excursion's; spider_3in
    /// itself takes its target's load.
    #[test]
    fn the_accelerated_sine_takes_the_load_of_the_excursion_it_reaches() {
        use springbench_core::physics::ageing::apply_sine;
        let part = springbench_core::physics::preset("spider_3in").unwrap();
        let mut stiff = part.clone();
        stiff.k_coeffs_si.iter_mut().for_each(|k| *k *= 400.0);
        let x = 0.0053;
        let mut vb = VirtualBench::new(stiff.clone(), 1).with_ageing(0.0);
        let reach = vb.sine_reach_m(x);
        assert!(reach < 0.01 * x, "{} mm", 1e3 * reach);
        let applied = vb.apply_sine_load(x, SINE_REACH_STEP_S);
        assert_eq!(applied.reach_m, reach);
        let added = applied.load_j;
        assert_eq!(added, apply_sine(&stiff, 0.0, reach, SINE_REACH_STEP_S));
        assert!(added < 1e-3 * apply_sine(&stiff, 0.0, x, SINE_REACH_STEP_S));
        let mut vb = VirtualBench::new(part.clone(), 1).with_ageing(0.0);
        assert_eq!(vb.sine_reach_m(x), x);
        assert_eq!(
            vb.apply_sine_load(x, 900.0).load_j,
            apply_sine(&part, 0.0, x, 900.0)
        );
    }

    fn sine(n: usize, f_hz: f64, v: f64) -> Vec<f64> {
        (0..n)
            .map(|k| v * (2.0 * std::f64::consts::PI * f_hz * k as f64 / 48000.0).sin())
            .collect()
    }

    #[test]
    fn a_bench_differs_by_its_laser_gain_and_clamp_mass() {
        let part = springbench_core::physics::preset("spider_4in").unwrap();
        let mut quiet = BenchParams::default();
        quiet.laser.noise_m = 0.0;
        let drive = sine(9600, 20.0, 2.0);
        let run = |cfg: VirtualConfig| {
            let mut b = VirtualBench::new(part.clone(), 7)
                .with_bench(quiet)
                .with_config(&cfg);
            b.run(&drive, &mut |_| Control::Continue).unwrap()
        };
        let base = run(VirtualConfig::default());
        let gain = run(VirtualConfig {
            laser_gain_error: 0.01,
            ..Default::default()
        });
        // Same motion, read 1 % high (24-bit codes over 25 mm: 3 nm).
        for (a, b) in base.displacement_m.iter().zip(&gain.displacement_m) {
            assert!((b - 1.01 * a).abs() < 1e-8, "{a} {b}");
        }
        let peak = |s: &Signals| s.displacement_m.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        assert!(peak(&base) > 1e-4);
        // A heavier clamp: the mounted part's moving mass grows by it.
        let b = VirtualBench::new(part.clone(), 7).with_config(&VirtualConfig {
            clamp_mass_kg: 0.001,
            ..Default::default()
        });
        assert_eq!(b.part.moving_mass_kg, part.moving_mass_kg + 0.001);
        // The bench's part effects: added to the part's (issue 33).
        let soft = springbench_core::effects::ReversibleSoftening {
            depth_n_per_m2: 3e4,
            tau_s: 2.0,
        };
        let cfg: VirtualConfig = toml::from_str(
            "[part_effects.reversible_softening]\ndepth_n_per_m2 = 3e4\ntau_s = 2.0\n",
        )
        .unwrap();
        let b = VirtualBench::new(part.clone(), 7).with_config(&cfg);
        assert_eq!(b.part.effects.reversible_softening, Some(soft));
        assert_eq!(b.part.moving_mass_kg, part.moving_mass_kg);
        assert!(cfg.validate("v").is_ok());
        let bad: VirtualConfig = toml::from_str(
            "[part_effects.reversible_softening]\ndepth_n_per_m2 = 3e4\ntau_s = 0.0\n",
        )
        .unwrap();
        assert_eq!(
            bad.validate("v").unwrap_err(),
            "bench 'v': virtual.part_effects.reversible_softening.tau_s must be > 0, got 0"
        );
    }
}
