//! The long-term test as a job (issue 32): the full procedure at intervals
//! while a sine held at the part's current resonance ages it in between.
//! `POST /api/v1/long-term-tests` takes a [`LongTermRequest`]; the accepted
//! [`LongTermSpec`] is stored with the job (`StoredRequest::LongTerm`) and
//! read back by the runner (`src/runner/longterm.rs`).

use super::parse::FieldError;
use super::request::JobRequest;
use super::spec::{Admission, JobSpec, ProcedureMode};
use serde::{Deserialize, Serialize};

/// Shortest interval (s): one measurement takes about 40 s of bench time.
pub const MIN_INTERVAL_S: f64 = 60.0;
/// Longest test (s): 30 days.
pub const MAX_DURATION_S: f64 = 30.0 * 86400.0;
/// Most measurements of one test.
pub const MAX_INTERVALS: usize = 2000;
/// Default failure limit: a change of K(0) by more than this (%).
pub const DEFAULT_K0_CHANGE_PERCENT: f64 = 60.0;
/// Default failure limit: the stimulus' excursion grown by more than this (%).
pub const DEFAULT_XPEAK_RUNAWAY_PERCENT: f64 = 30.0;
/// Most level steps of one stimulus.
pub const MAX_LEVEL_STEPS: usize = 100;
/// A noise's band lies within these (Hz): a suspension's stroke is below
/// a few hundred hertz; 1 Hz is the slowest a bench's exciter follows.
pub const NOISE_BAND_HZ: (f64, f64) = (1.0, 2000.0);
/// A noise's band is at least this wide (Hz): four lines of its 4-s loop.
pub const MIN_NOISE_BANDWIDTH_HZ: f64 = 1.0;
/// The peaks of Gaussian noise reach about this many times its RMS
/// (`physics::waveform::CREST`).
pub use crate::physics::waveform::CREST;

/// A stimulus id: the SHA-256 of the WAV file's bytes, 64 lowercase hex digits.
pub fn is_wav_id(id: &str) -> bool {
    id.len() == 64
        && id
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

fn kind_name(k: StimulusKind) -> &'static str {
    match k {
        StimulusKind::Sine => "sine",
        StimulusKind::Noise => "noise",
        StimulusKind::Wav => "wav",
    }
}

/// What the stimulus holds as the part changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Hold {
    /// The excursion: the drive follows the part (the default).
    #[default]
    Excursion,
    /// The drive level that gave `excursion_m` on the part at the test's
    /// start, as an endurance test holds its voltage: the excursion follows
    /// the part, and runs away when the part collapses.
    Drive,
}

/// What the stimulus plays (decision 0137).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StimulusKind {
    /// A sine held at the part's current resonance, its level the peak
    /// displacement `excursion_m` (the default: every stored test is one).
    #[default]
    Sine,
    /// Band-limited Gaussian noise (`band_hz`), its level the RMS
    /// displacement `excursion_rms_m` held closed-loop on the measured
    /// displacement.
    Noise,
    /// A WAV file uploaded to the station (`POST /api/v1/stimuli`, named by
    /// `wav_id`) played as a loop, its level the RMS displacement
    /// `excursion_rms_m` as for the noise (decision 0144).
    Wav,
}

impl StimulusKind {
    fn is_sine(&self) -> bool {
        *self == StimulusKind::Sine
    }

    /// The field that gives this kind's level.
    pub fn level_field(&self) -> &'static str {
        match self {
            StimulusKind::Sine => "excursion_m",
            StimulusKind::Noise | StimulusKind::Wav => "excursion_rms_m",
        }
    }

    /// A loop of drive samples held at an RMS displacement (noise, WAV file).
    pub fn is_loop(&self) -> bool {
        !self.is_sine()
    }
}

/// A level step of the stimulus (decision 0132): from test time `from_s`
/// on, the stimulus is held at the step's level (until the next step): a
/// sine's `excursion_m`, a noise's `excursion_rms_m`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct LevelStep {
    /// Test time from which this level holds (s, > 0; the level before the
    /// first step is the stimulus' own).
    pub from_s: f64,
    /// A sine's peak displacement from then on (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub excursion_m: Option<f64>,
    /// A noise's RMS displacement from then on (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub excursion_rms_m: Option<f64>,
}

impl LevelStep {
    /// The step's level in its stimulus' measure (m; 0 when absent, which
    /// validation refuses).
    pub fn level_m(&self, kind: StimulusKind) -> f64 {
        match kind {
            StimulusKind::Sine => self.excursion_m,
            StimulusKind::Noise | StimulusKind::Wav => self.excursion_rms_m,
        }
        .unwrap_or(0.0)
    }
}

/// The stimulus between two measurements.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Stimulus {
    /// `sine` (the default) or `noise` (decision 0137).
    #[serde(default, skip_serializing_if = "StimulusKind::is_sine")]
    pub kind: StimulusKind,
    /// A sine's level: its peak displacement held at the part's current
    /// resonance (m), from the test's start (until the first of `steps`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub excursion_m: Option<f64>,
    /// A noise's level: the RMS of the part's displacement (m), from the
    /// test's start. Its peaks reach about 4 times it: 4 × the level must
    /// stay within the bench's displacement limit, which is checked on
    /// every block as for the sine.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub excursion_rms_m: Option<f64>,
    /// A noise's band (Hz, [low, high]): a flat spectrum within it, nothing outside.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub band_hz: Option<[f64; 2]>,
    /// A WAV stimulus' file: the id `POST /api/v1/stimuli` answered (the
    /// SHA-256 of its bytes, 64 hex digits).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wav_id: Option<String>,
    /// Level stepping: the level changes at these test times (sorted,
    /// each after the one before, within the test; at most 100). Each
    /// level holds from its `from_s` to the next step's.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub steps: Vec<LevelStep>,
    /// On/off cycling: seconds on, then `off_s` seconds off (both or neither).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub on_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub off_s: Option<f64>,
    /// `excursion` (default) or `drive` (a sine only).
    #[serde(default)]
    pub hold: Hold,
}

impl Stimulus {
    /// A sine at a peak displacement (m), without steps or cycling.
    pub fn sine(excursion_m: f64) -> Stimulus {
        Stimulus {
            excursion_m: Some(excursion_m),
            ..Stimulus::default()
        }
    }

    /// The level from the test's start (m) in the kind's measure: a sine's
    /// peak, a noise's RMS displacement.
    pub fn start_level_m(&self) -> f64 {
        match self.kind {
            StimulusKind::Sine => self.excursion_m,
            StimulusKind::Noise | StimulusKind::Wav => self.excursion_rms_m,
        }
        .unwrap_or(0.0)
    }

    /// The target level at test time `t_s` (m) in the kind's measure (a
    /// sine's peak displacement, a noise's RMS): the last step begun by
    /// then, else the start level.
    pub fn excursion_at_m(&self, t_s: f64) -> f64 {
        self.steps
            .iter()
            .rev()
            .find(|s| s.from_s <= t_s)
            .map_or(self.start_level_m(), |s| s.level_m(self.kind))
    }

    /// The first level change after test time `t_s` (s), if any.
    pub fn next_change_s(&self, t_s: f64) -> Option<f64> {
        self.steps.iter().map(|s| s.from_s).find(|&f| f > t_s)
    }

    /// The stimulus between test times `a_s` and `b_s` split at its level
    /// changes: (seconds on, target excursion in m) per piece of constant
    /// level, in order (a piece whose level is cycled off counts 0 s on).
    pub fn pieces(&self, a_s: f64, b_s: f64) -> Vec<(f64, f64)> {
        let mut out = vec![];
        let mut t = a_s;
        while t < b_s {
            let end = self.next_change_s(t).map_or(b_s, |c| c.min(b_s));
            out.push((self.on_time_s(t, end), self.excursion_at_m(t)));
            t = end;
        }
        out
    }

    /// Seconds of stimulus on between test times `a_s` and `b_s` (the
    /// cycle's phase runs from the test's start, so a resumed test keeps it).
    pub fn on_time_s(&self, a_s: f64, b_s: f64) -> f64 {
        if b_s <= a_s {
            return 0.0;
        }
        let (Some(on), Some(off)) = (self.on_s, self.off_s) else {
            return b_s - a_s;
        };
        let period = on + off;
        // on-time in [0, t)
        let upto = |t: f64| {
            let n = (t / period).floor();
            n * on + (t - n * period).min(on)
        };
        upto(b_s) - upto(a_s)
    }
}

/// Limits that stop the test.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct FailureLimits {
    /// Largest change of the small-signal K(0) from the first interval (%,
    /// either way). The test also stops when no resonance is found.
    #[serde(default = "default_k0_change")]
    pub k0_change_percent: f64,
    /// Largest growth of the stimulus' peak displacement over its value at
    /// the test's start (%): a stimulus held at a drive level (`hold:
    /// drive`) whose excursion runs away as the part collapses.
    #[serde(default = "default_xpeak_runaway")]
    pub xpeak_runaway_percent: f64,
}

fn default_k0_change() -> f64 {
    DEFAULT_K0_CHANGE_PERCENT
}

fn default_xpeak_runaway() -> f64 {
    DEFAULT_XPEAK_RUNAWAY_PERCENT
}

impl Default for FailureLimits {
    fn default() -> Self {
        FailureLimits {
            k0_change_percent: DEFAULT_K0_CHANGE_PERCENT,
            xpeak_runaway_percent: DEFAULT_XPEAK_RUNAWAY_PERCENT,
        }
    }
}

/// `POST /api/v1/long-term-tests`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct LongTermRequest {
    /// The measurement made at each interval: a measurement job's request
    /// (part, bench, level, mounted part...); one repeat, full procedure.
    pub measurement: JobRequest,
    /// Length of the test in test time (s).
    pub duration_s: Option<f64>,
    /// Time between the starts of two measurements (s, at least 60).
    pub interval_s: Option<f64>,
    /// The stimulus between the measurements.
    pub stimulus: Option<Stimulus>,
    /// Virtual bench: run faster than real time (default true); results say
    /// so. A hardware or emulated bench plays the stimulus in real time:
    /// false (its default; true is refused).
    pub accelerated: Option<bool>,
    #[serde(default)]
    pub failure_limits: Option<FailureLimits>,
    /// Predict K(0) at this test time with the fitted law (s; default twice the duration).
    pub predict_s: Option<f64>,
}

/// A long-term test as accepted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LongTermSpec {
    pub measurement: JobSpec,
    pub duration_s: f64,
    pub interval_s: f64,
    pub stimulus: Stimulus,
    pub accelerated: bool,
    pub failure_limits: FailureLimits,
    pub predict_s: f64,
}

impl LongTermSpec {
    /// Number of measurements: one at the start and one per interval.
    pub fn intervals(&self) -> usize {
        (self.duration_s / self.interval_s + 1e-9).floor() as usize + 1
    }
}

/// The part's state, as persisted after each interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PartState {
    /// The load the part has taken (J): simulated on a virtual bench,
    /// measured from the stimulus' displacement on a hardware or emulated
    /// one (`ageing::load_from_displacement_j`).
    pub load_j: f64,
    /// Its stiffness at rest then (N/m): the virtual part's truth, the
    /// emulated part's (aged by the emulator at `true_load_j`); unknown
    /// (null) on a real bench.
    #[serde(default)]
    pub k0_true_n_per_m: Option<f64>,
    /// The load the part has truly taken (J), as `load_j` after the last
    /// interval's measurement: the virtual part's simulated load (equal to
    /// `load_j`), the emulated part's as the emulator counted it sample by
    /// sample (a resumed test hands it to the new emulator, decision
    /// 0135); unknown (null) on a real bench.
    #[serde(default)]
    pub true_load_j: Option<f64>,
}

/// A failure limit that stopped the test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Failure {
    /// `k0_change_percent`, `xpeak_runaway_percent` or `no_resonance`.
    pub limit: String,
    /// The interval at which it was reached (for a limit of the stimulus:
    /// the interval whose stimulus it stopped, not measured).
    pub interval: usize,
    /// Test time at which it was reached (s), for a limit of the stimulus.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_s: Option<f64>,
    /// The value and the bound (`k0_change_percent`), when the limit has them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bound: Option<f64>,
    pub detail: String,
}

/// Lowest and highest air temperature taken for a reading (K): −100 and
/// +150 °C. Outside, the number is a mistake of unit (23 entered for 23 °C)
/// or a broken sensor, not the air around a bench.
pub const AMBIENT_TEMPERATURE_RANGE_K: (f64, f64) = (173.15, 423.15);

/// The air around the bench at an interval (issue 32, decision 0130): from
/// the bench's configured sensor or entered by hand. SI units; the page
/// shows the temperature in °C.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Ambient {
    /// Air temperature (K).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temperature_k: Option<f64>,
    /// Relative humidity (%, 0 to 100).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relative_humidity_percent: Option<f64>,
}

impl Ambient {
    /// One message per value out of its range (never a stored NaN).
    pub fn check(&self) -> Vec<FieldError> {
        let mut errors = vec![];
        let (lo, hi) = AMBIENT_TEMPERATURE_RANGE_K;
        if let Some(t) = self.temperature_k {
            if !(t.is_finite() && (lo..=hi).contains(&t)) {
                let hint = if t.is_finite() && (-100.0..=150.0).contains(&t) {
                    format!(" ({t} °C is {} K)", t + 273.15)
                } else {
                    String::new()
                };
                errors.push(FieldError::new(
                    "temperature_k",
                    format!(
                        "must be an air temperature in kelvin within {lo} to {hi} K (−100 to 150 °C), got {t}{hint}"
                    ),
                ));
            }
        }
        if let Some(h) = self.relative_humidity_percent {
            if !(h.is_finite() && (0.0..=100.0).contains(&h)) {
                errors.push(FieldError::new(
                    "relative_humidity_percent",
                    format!("must be a relative humidity within 0 to 100 %, got {h}"),
                ));
            }
        }
        errors
    }
}

/// `PUT /api/v1/long-term-tests/{id}/intervals/{index}/ambient`: the
/// ambient conditions of a finished interval entered by hand (either or
/// both; a value given replaces the sensor's).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct AmbientRequest {
    /// Air temperature (K).
    pub temperature_k: Option<f64>,
    /// Relative humidity (%, 0 to 100).
    pub relative_humidity_percent: Option<f64>,
}

impl AmbientRequest {
    /// A body checked whole (`parsed` is [`super::parse_lenient`]'s answer).
    pub fn check(
        parsed: (Option<AmbientRequest>, Vec<FieldError>),
    ) -> Result<Ambient, Vec<FieldError>> {
        let (req, mut errors) = parsed;
        let Some(req) = req else {
            return Err(errors);
        };
        let a = Ambient {
            temperature_k: req.temperature_k,
            relative_humidity_percent: req.relative_humidity_percent,
        };
        for e in a.check() {
            if !errors.iter().any(|x| x.field == e.field) {
                errors.push(e);
            }
        }
        if errors.is_empty() && a.temperature_k.is_none() && a.relative_humidity_percent.is_none() {
            errors.push(FieldError::new(
                "temperature_k",
                "give temperature_k (K) or relative_humidity_percent (%), or both",
            ));
        }
        if errors.is_empty() {
            Ok(a)
        } else {
            Err(errors)
        }
    }
}

fn prefixed(e: FieldError) -> FieldError {
    let field = if e.field.is_empty() {
        "measurement".to_string()
    } else {
        format!("measurement.{}", e.field)
    };
    FieldError::new(field, e.message)
}

impl LongTermRequest {
    /// A body checked whole, one message per bad field (`parsed` is
    /// [`super::parse_lenient`]'s answer).
    pub fn check(
        parsed: (Option<LongTermRequest>, Vec<FieldError>),
        adm: &Admission,
    ) -> Result<LongTermSpec, Vec<FieldError>> {
        let (req, mut errors) = parsed;
        let Some(req) = req else {
            return Err(errors);
        };
        let mut add = |e: FieldError| {
            if !errors.iter().any(|x| x.field == e.field) {
                errors.push(e);
            }
        };
        let m = &req.measurement;
        if m.repeats.is_some_and(|r| r != 1) {
            add(FieldError::new(
                "measurement.repeats",
                "a long-term test measures once per interval: 1 or absent",
            ));
        }
        if m.procedure.is_some_and(|p| p != ProcedureMode::Full) {
            add(FieldError::new(
                "measurement.procedure",
                "a long-term test runs the full procedure at each interval",
            ));
        }
        if m.recipe.is_some() {
            add(FieldError::new(
                "measurement.recipe",
                "a long-term test is not judged by a recipe",
            ));
        }
        let spec = match req.measurement.clone().validate(adm) {
            Ok(s) => Some(s),
            Err(es) => {
                for e in es {
                    add(prefixed(e));
                }
                None
            }
        };
        let num = |v: Option<f64>, field: &str, add: &mut dyn FnMut(FieldError)| match v {
            None => {
                add(FieldError::new(field, "required (s)"));
                None
            }
            Some(x) if !x.is_finite() => {
                add(FieldError::new(field, "must be a finite number"));
                None
            }
            Some(x) => Some(x),
        };
        let interval = num(req.interval_s, "interval_s", &mut add).and_then(|x| {
            if x < MIN_INTERVAL_S {
                add(FieldError::new(
                    "interval_s",
                    format!(
                        "must be at least {MIN_INTERVAL_S} s (a measurement takes about 40 s), got {x}"
                    ),
                ));
                None
            } else {
                Some(x)
            }
        });
        let duration = num(req.duration_s, "duration_s", &mut add).and_then(|x| {
            if !(x > 0.0 && x <= MAX_DURATION_S) {
                add(FieldError::new(
                    "duration_s",
                    format!("must be in (0, {MAX_DURATION_S}] s, got {x}"),
                ));
                None
            } else {
                Some(x)
            }
        });
        if let (Some(i), Some(d)) = (interval, duration) {
            if i > d {
                add(FieldError::new(
                    "interval_s",
                    format!("{i} s is longer than the test (duration_s {d} s)"),
                ));
            } else if d / i + 1.0 > MAX_INTERVALS as f64 {
                add(FieldError::new(
                    "interval_s",
                    format!(
                        "{} measurements: at most {MAX_INTERVALS} per test",
                        (d / i).floor() + 1.0
                    ),
                ));
            }
        }
        // The job's limit, or its bench's when the measurement was refused.
        let max_x = spec
            .as_ref()
            .map(|s| s.limits.max_displacement_m)
            .or_else(|| {
                let b = match &m.bench {
                    Some(id) => adm.benches.iter().find(|b| &b.id == id),
                    None => adm.benches.first(),
                };
                b.map(|b| b.limits.max_displacement_m)
            });
        match &req.stimulus {
            None => add(FieldError::new(
                "stimulus",
                "required: {\"excursion_m\": peak displacement of the sine at resonance}",
            )),
            Some(s) => {
                let kind = s.kind;
                // A level in the kind's measure: a sine's peak within the
                // displacement limit, a noise's RMS whose peaks (about
                // CREST times it) are.
                let check_level =
                    |x: Option<f64>, field: String, add: &mut dyn FnMut(FieldError)| {
                        let Some(x) = x else {
                            add(FieldError::new(
                                field,
                                match kind {
                                    StimulusKind::Sine => {
                                        "required: the sine's peak displacement (m)"
                                    }
                                    StimulusKind::Noise | StimulusKind::Wav => {
                                        "required: the RMS displacement (m) the stimulus is held at"
                                    }
                                },
                            ));
                            return;
                        };
                        let what = match kind {
                            StimulusKind::Sine => "a peak displacement",
                            StimulusKind::Noise | StimulusKind::Wav => "an RMS displacement",
                        };
                        if !(x.is_finite() && x >= 0.0) {
                            add(FieldError::new(
                                field,
                                format!("must be {what} >= 0 m, got {x}"),
                            ));
                            return;
                        }
                        let Some(mx) = max_x else { return };
                        match kind {
                        StimulusKind::Sine if x > mx => add(FieldError::new(
                            field,
                            format!("{x} m is beyond the bench's displacement limit ({mx} m)"),
                        )),
                        StimulusKind::Noise | StimulusKind::Wav if CREST * x > mx => add(FieldError::new(
                            field,
                            format!(
                                "{x} m RMS: the stimulus' peaks reach about {CREST} times it ({} m), beyond the bench's displacement limit ({mx} m); at most {} m",
                                CREST * x,
                                mx / CREST
                            ),
                        )),
                        _ => {}
                    }
                    };
                // The other kind's fields are a mistake, not ignored.
                let foreign: &[(&str, bool)] = match kind {
                    StimulusKind::Sine => &[
                        ("excursion_rms_m", s.excursion_rms_m.is_some()),
                        ("band_hz", s.band_hz.is_some()),
                        ("wav_id", s.wav_id.is_some()),
                    ],
                    StimulusKind::Noise => &[
                        ("excursion_m", s.excursion_m.is_some()),
                        ("wav_id", s.wav_id.is_some()),
                    ],
                    StimulusKind::Wav => &[
                        ("excursion_m", s.excursion_m.is_some()),
                        ("band_hz", s.band_hz.is_some()),
                    ],
                };
                for (f, given) in foreign {
                    if *given {
                        add(FieldError::new(
                            format!("stimulus.{f}"),
                            format!(
                                "not a field of a {} stimulus (its level is {})",
                                kind_name(kind),
                                kind.level_field()
                            ),
                        ));
                    }
                }
                let level = match kind {
                    StimulusKind::Sine => s.excursion_m,
                    StimulusKind::Noise | StimulusKind::Wav => s.excursion_rms_m,
                };
                if kind == StimulusKind::Wav {
                    match s.wav_id.as_deref() {
                        None => add(FieldError::new(
                            "stimulus.wav_id",
                            "required: the id POST /api/v1/stimuli answered for the WAV file",
                        )),
                        Some(id) if !is_wav_id(id) => add(FieldError::new(
                            "stimulus.wav_id",
                            format!("must be a stimulus id (64 lowercase hex digits, the SHA-256 of the file), got '{id}'"),
                        )),
                        Some(_) => {}
                    }
                    if s.hold == Hold::Drive {
                        add(FieldError::new(
                            "stimulus.hold",
                            "a WAV file is held at its excursion (the RMS displacement); a drive level is held for a sine only",
                        ));
                    }
                }
                check_level(level, format!("stimulus.{}", kind.level_field()), &mut add);
                if kind == StimulusKind::Noise {
                    match s.band_hz {
                        None => add(FieldError::new(
                            "stimulus.band_hz",
                            format!("required: the noise's band [low, high] (Hz, within {NOISE_BAND_HZ:?})"),
                        )),
                        Some([lo, hi]) => {
                            let (min, max) = NOISE_BAND_HZ;
                            if !(lo.is_finite() && hi.is_finite() && lo >= min && hi <= max && hi - lo >= MIN_NOISE_BANDWIDTH_HZ) {
                                add(FieldError::new(
                                    "stimulus.band_hz",
                                    format!("must be [low, high] within {min} to {max} Hz, high at least {MIN_NOISE_BANDWIDTH_HZ} Hz above low, got [{lo}, {hi}]"),
                                ));
                            }
                        }
                    }
                    if s.hold == Hold::Drive {
                        add(FieldError::new(
                            "stimulus.hold",
                            "a noise is held at its excursion (the RMS displacement); a drive level is held for a sine only",
                        ));
                    }
                }
                if s.steps.len() > MAX_LEVEL_STEPS {
                    add(FieldError::new(
                        "stimulus.steps",
                        format!("{} level steps: at most {MAX_LEVEL_STEPS}", s.steps.len()),
                    ));
                }
                let mut before: Option<f64> = None;
                for (i, st) in s.steps.iter().enumerate() {
                    let f = st.from_s;
                    let field = format!("stimulus.steps[{i}].from_s");
                    if !(f.is_finite() && f > 0.0) {
                        add(FieldError::new(
                            field,
                            format!("must be a test time > 0 s (the level at the start is stimulus.{}), got {f}", kind.level_field()),
                        ));
                    } else if let Some(b) = before.filter(|b| f <= *b) {
                        add(FieldError::new(
                            field,
                            format!("steps must be sorted by from_s, each after the one before: {f} s is not after {b} s"),
                        ));
                    } else if let Some(d) = duration.filter(|d| f >= *d) {
                        add(FieldError::new(
                            field,
                            format!("{f} s is not within the test (duration_s {d} s)"),
                        ));
                    }
                    if f.is_finite() {
                        before = Some(before.map_or(f, |b: f64| b.max(f)));
                    }
                    let (given, other, other_field) = match kind {
                        StimulusKind::Sine => {
                            (st.excursion_m, st.excursion_rms_m, "excursion_rms_m")
                        }
                        StimulusKind::Noise | StimulusKind::Wav => {
                            (st.excursion_rms_m, st.excursion_m, "excursion_m")
                        }
                    };
                    if other.is_some() {
                        add(FieldError::new(
                            format!("stimulus.steps[{i}].{other_field}"),
                            format!(
                                "not a field of a {} stimulus' step (its level is {})",
                                kind_name(kind),
                                kind.level_field()
                            ),
                        ));
                    }
                    check_level(
                        given,
                        format!("stimulus.steps[{i}].{}", kind.level_field()),
                        &mut add,
                    );
                }
                match (s.on_s, s.off_s) {
                    (None, None) => {}
                    (Some(on), Some(off)) => {
                        if !(on.is_finite() && on > 0.0) {
                            add(FieldError::new("stimulus.on_s", "must be > 0 s"));
                        }
                        if !(off.is_finite() && off >= 0.0) {
                            add(FieldError::new("stimulus.off_s", "must be >= 0 s"));
                        }
                    }
                    (Some(_), None) => add(FieldError::new(
                        "stimulus.off_s",
                        "on/off cycling needs both on_s and off_s",
                    )),
                    (None, Some(_)) => add(FieldError::new(
                        "stimulus.on_s",
                        "on/off cycling needs both on_s and off_s",
                    )),
                }
            }
        }
        let limits = req.failure_limits.unwrap_or_default();
        if !(limits.k0_change_percent.is_finite() && limits.k0_change_percent > 0.0) {
            add(FieldError::new(
                "failure_limits.k0_change_percent",
                format!("must be > 0 %, got {}", limits.k0_change_percent),
            ));
        }
        if !(limits.xpeak_runaway_percent.is_finite() && limits.xpeak_runaway_percent > 0.0) {
            add(FieldError::new(
                "failure_limits.xpeak_runaway_percent",
                format!("must be > 0 %, got {}", limits.xpeak_runaway_percent),
            ));
        }
        if let Some(p) = req.predict_s {
            if !(p.is_finite() && p > 0.0) {
                add(FieldError::new(
                    "predict_s",
                    format!("must be > 0 s, got {p}"),
                ));
            }
        }
        match (spec, interval, duration, req.stimulus) {
            (Some(measurement), Some(interval_s), Some(duration_s), Some(stimulus))
                if errors.is_empty() =>
            {
                Ok(LongTermSpec {
                    measurement,
                    duration_s,
                    interval_s,
                    stimulus,
                    accelerated: req.accelerated.unwrap_or(true),
                    failure_limits: limits,
                    predict_s: req.predict_s.unwrap_or(2.0 * duration_s),
                })
            }
            _ => Err(errors),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{BenchOffer, Limits};
    use serde_json::json;

    fn adm() -> Admission {
        Admission {
            benches: vec![BenchOffer {
                id: "b1".into(),
                limits: Limits {
                    max_displacement_m: 0.012,
                    max_drive_v: 100.0,
                },
                preset: "spider_3in".into(),
            }],
            target_xpeak_m: 0.006,
            method: crate::identify::Method::TwoSignal,
            order: None,
        }
    }

    fn check(body: serde_json::Value) -> Result<LongTermSpec, Vec<FieldError>> {
        LongTermRequest::check(crate::job::parse_lenient(&body), &adm())
    }

    #[test]
    fn a_test_is_accepted_with_its_defaults() {
        let s = check(json!({"measurement": {"part": {"serial": "LT-1"}},
            "duration_s": 3600.0, "interval_s": 900.0, "stimulus": {"excursion_m": 0.005}}))
        .unwrap();
        assert_eq!(s.intervals(), 5);
        assert!(s.accelerated);
        assert_eq!(s.predict_s, 7200.0);
        assert_eq!(s.measurement.levels_m, vec![0.006]);
        assert_eq!(s.failure_limits.k0_change_percent, 60.0);
    }

    #[test]
    fn every_bad_field_is_named() {
        let e = check(json!({"measurement": {"part": {"serial": "LT-1"}, "repeats": 3},
            "duration_s": 600.0, "interval_s": 900.0, "stimulus": {"excursion_m": -0.001, "on_s": 5.0},
            "failure_limits": {"k0_change_percent": 0.0}}))
        .unwrap_err();
        let fields: Vec<&str> = e.iter().map(|e| e.field.as_str()).collect();
        for f in [
            "measurement.repeats",
            "interval_s",
            "stimulus.excursion_m",
            "stimulus.off_s",
            "failure_limits.k0_change_percent",
        ] {
            assert!(fields.contains(&f), "{f} not in {e:?}");
        }
        let iv = e.iter().find(|e| e.field == "interval_s").unwrap();
        assert!(iv.message.contains("longer than the test"), "{iv:?}");
        let e = check(
            json!({"measurement": {"part": {"serial": "../x"}}, "duration_s": 600.0,
            "interval_s": 60.0, "stimulus": {"excursion_m": 0.02}}),
        )
        .unwrap_err();
        let fields: Vec<&str> = e.iter().map(|e| e.field.as_str()).collect();
        assert!(fields.contains(&"measurement.part.serial"), "{e:?}");
        assert!(fields.contains(&"stimulus.excursion_m"), "{e:?}");
    }

    #[test]
    fn on_off_cycling_counts_the_on_time_from_the_tests_start() {
        let s = Stimulus {
            on_s: Some(60.0),
            off_s: Some(30.0),
            ..Stimulus::sine(0.005)
        };
        assert_eq!(s.on_time_s(0.0, 90.0), 60.0);
        assert_eq!(s.on_time_s(0.0, 900.0), 600.0);
        assert_eq!(s.on_time_s(45.0, 100.0), 15.0 + 10.0);
        // split anywhere: the same on-time
        assert!((s.on_time_s(0.0, 500.0) + s.on_time_s(500.0, 900.0) - 600.0).abs() < 1e-9);
        let c = Stimulus {
            on_s: None,
            off_s: None,
            ..s.clone()
        };
        assert_eq!(c.on_time_s(10.0, 20.0), 10.0);
    }

    #[test]
    fn ambient_values_out_of_range_are_named() {
        let check = |b: serde_json::Value| AmbientRequest::check(crate::job::parse_lenient(&b));
        let a = check(json!({"temperature_k": 296.15, "relative_humidity_percent": 45.0})).unwrap();
        assert_eq!(a.temperature_k, Some(296.15));
        assert_eq!(a.relative_humidity_percent, Some(45.0));
        let a = check(json!({"relative_humidity_percent": 0.0})).unwrap();
        assert_eq!(a.temperature_k, None);
        for (b, field) in [
            (json!({"temperature_k": 23.0}), "temperature_k"),
            (json!({"temperature_k": -1.0}), "temperature_k"),
            (json!({"temperature_k": "NaN"}), "temperature_k"),
            (
                json!({"relative_humidity_percent": 100.5}),
                "relative_humidity_percent",
            ),
            (
                json!({"relative_humidity_percent": -0.1}),
                "relative_humidity_percent",
            ),
            (json!({}), "temperature_k"),
            (json!({"temperature_c": 23.0}), "temperature_c"),
        ] {
            let e = check(b.clone()).unwrap_err();
            assert!(e.iter().any(|e| e.field == field), "{b}: {e:?}");
        }
        let e = check(json!({"temperature_k": 23.0})).unwrap_err();
        assert!(e[0].message.contains("296.15 K"), "{e:?}");
        assert!(
            Ambient {
                temperature_k: Some(f64::NAN),
                relative_humidity_percent: Some(f64::INFINITY)
            }
            .check()
            .len()
                == 2
        );
    }

    #[test]
    fn level_steps_split_the_stimulus_at_their_times() {
        let s = check(json!({"measurement": {"part": {"serial": "LT-1"}},
            "duration_s": 3600.0, "interval_s": 900.0,
            "stimulus": {"excursion_m": 0.004, "on_s": 60.0, "off_s": 30.0,
                "steps": [{"from_s": 1000.0, "excursion_m": 0.006}, {"from_s": 2000.0, "excursion_m": 0.0}]}}))
        .unwrap()
        .stimulus;
        assert_eq!(s.excursion_at_m(0.0), 0.004);
        assert_eq!(s.excursion_at_m(999.9), 0.004);
        assert_eq!(s.excursion_at_m(1000.0), 0.006);
        assert_eq!(s.excursion_at_m(2500.0), 0.0);
        assert_eq!(s.next_change_s(0.0), Some(1000.0));
        assert_eq!(s.next_change_s(1000.0), Some(2000.0));
        assert_eq!(s.next_change_s(2000.0), None);
        // 900..2100 s: cycles of 60 s on / 30 s off from 0 s. By hand: on
        // [900, 960), [990, 1000) -> 70 s at 4 mm; [1000, 1050), [1080,
        // 1140), ... [1980, 2000) -> 50 + 10*60 + 20 = 670 s at 6 mm (the
        // last cycle [1980, 2040) cut at 2000); [2000, 2040), [2070, 2100)
        // -> 70 s at 0 mm.
        let p = s.pieces(900.0, 2100.0);
        assert_eq!(p.len(), 3, "{p:?}");
        assert!((p[0].0 - 70.0).abs() < 1e-9 && p[0].1 == 0.004, "{p:?}");
        assert!((p[1].0 - 670.0).abs() < 1e-9 && p[1].1 == 0.006, "{p:?}");
        assert!((p[2].0 - 70.0).abs() < 1e-9 && p[2].1 == 0.0, "{p:?}");
        // the pieces' on-time is the cycle's whole on-time
        let whole: f64 = p.iter().map(|p| p.0).sum();
        assert!((whole - s.on_time_s(900.0, 2100.0)).abs() < 1e-9);
        // the document keeps the steps; a stimulus without steps keeps its form
        let v = serde_json::to_value(&s).unwrap();
        assert_eq!(
            v["steps"][0],
            json!({"from_s": 1000.0, "excursion_m": 0.006})
        );
        // ... and a sine's document keeps its form (no `kind`: old tests read alike)
        assert!(
            v.get("kind").is_none() && v.get("excursion_rms_m").is_none(),
            "{v}"
        );
        let c = check(json!({"measurement": {"part": {"serial": "LT-1"}},
            "duration_s": 3600.0, "interval_s": 900.0, "stimulus": {"excursion_m": 0.004}}))
        .unwrap()
        .stimulus;
        assert!(serde_json::to_value(&c).unwrap().get("steps").is_none());
        assert_eq!(c.pieces(0.0, 100.0), vec![(100.0, 0.004)]);
    }

    #[test]
    fn bad_level_steps_are_named() {
        let e = check(json!({"measurement": {"part": {"serial": "LT-1"}},
            "duration_s": 3600.0, "interval_s": 900.0,
            "stimulus": {"excursion_m": 0.004, "steps": [
                {"from_s": 0.0, "excursion_m": 0.005},
                {"from_s": 2000.0, "excursion_m": -0.001},
                {"from_s": 1500.0, "excursion_m": 0.02},
                {"from_s": 3600.0, "excursion_m": 0.004}]}}))
        .unwrap_err();
        let msg = |f: &str| {
            e.iter()
                .find(|e| e.field == f)
                .unwrap_or_else(|| panic!("{f} not in {e:?}"))
                .message
                .clone()
        };
        assert!(msg("stimulus.steps[0].from_s").contains("> 0 s"));
        assert!(msg("stimulus.steps[1].excursion_m").contains(">= 0 m"));
        assert!(msg("stimulus.steps[2].from_s").contains("sorted"));
        assert!(msg("stimulus.steps[2].excursion_m").contains("displacement limit (0.012 m)"));
        assert!(msg("stimulus.steps[3].from_s").contains("within the test"));
        assert!(
            !e.iter().any(|e| e.field == "stimulus.steps[1].from_s"),
            "{e:?}"
        );
        let e = check(json!({"measurement": {"part": {"serial": "LT-1"}},
            "duration_s": 3600.0, "interval_s": 900.0,
            "stimulus": {"excursion_m": 0.004, "steps": [{"from_s": "NaN", "excursion_m": 0.004}]}}))
        .unwrap_err();
        assert!(
            e.iter().any(|e| e.field.starts_with("stimulus.steps")),
            "{e:?}"
        );
    }

    #[test]
    fn a_noise_stimulus_is_accepted_and_steps_at_its_rms_level() {
        let s = check(json!({"measurement": {"part": {"serial": "LT-1"}},
            "duration_s": 3600.0, "interval_s": 900.0,
            "stimulus": {"kind": "noise", "band_hz": [20.0, 200.0], "excursion_rms_m": 0.002,
                "on_s": 60.0, "off_s": 30.0,
                "steps": [{"from_s": 1000.0, "excursion_rms_m": 0.003}]}}))
        .unwrap()
        .stimulus;
        assert_eq!(s.kind, StimulusKind::Noise);
        assert_eq!(s.excursion_at_m(0.0), 0.002);
        assert_eq!(s.excursion_at_m(1000.0), 0.003);
        let p = s.pieces(900.0, 2100.0);
        assert_eq!(p.len(), 2, "{p:?}");
        assert!((p[0].0 - 70.0).abs() < 1e-9 && p[0].1 == 0.002, "{p:?}");
        let v = serde_json::to_value(&s).unwrap();
        assert_eq!(v["kind"], "noise");
        assert_eq!(v["band_hz"], json!([20.0, 200.0]));
        // A stored sine (no kind) reads as a sine.
        let old: Stimulus = serde_json::from_value(json!({"excursion_m": 0.004})).unwrap();
        assert_eq!(old, Stimulus::sine(0.004));
        assert_eq!(old.excursion_at_m(0.0), 0.004);
    }

    #[test]
    fn bad_noise_fields_are_named() {
        let fields = |stim: serde_json::Value| {
            let e = check(json!({"measurement": {"part": {"serial": "LT-1"}},
                "duration_s": 3600.0, "interval_s": 900.0, "stimulus": stim}))
            .unwrap_err();
            e.into_iter()
                .map(|e| (e.field, e.message))
                .collect::<Vec<_>>()
        };
        let has = |e: &[(String, String)], f: &str, m: &str| {
            assert!(
                e.iter().any(|(ef, em)| ef == f && em.contains(m)),
                "{f} / {m} not in {e:?}"
            )
        };
        // 4 x 3.1 mm = 12.4 mm is beyond the 12 mm limit; 3 mm is not.
        let e =
            fields(json!({"kind": "noise", "band_hz": [20.0, 200.0], "excursion_rms_m": 0.0031}));
        has(&e, "stimulus.excursion_rms_m", "at most 0.003 m");
        assert!(check(json!({"measurement": {"part": {"serial": "LT-1"}},
            "duration_s": 3600.0, "interval_s": 900.0,
            "stimulus": {"kind": "noise", "band_hz": [20.0, 200.0], "excursion_rms_m": 0.003}}))
        .is_ok());
        let e = fields(json!({"kind": "noise", "excursion_m": 0.002}));
        has(&e, "stimulus.band_hz", "required");
        has(&e, "stimulus.excursion_rms_m", "required");
        has(
            &e,
            "stimulus.excursion_m",
            "not a field of a noise stimulus",
        );
        for band in [
            json!([200.0, 20.0]),
            json!([0.0, 20.0]),
            json!([20.0, 5000.0]),
            json!([20.0, 20.5]),
        ] {
            let e = fields(json!({"kind": "noise", "band_hz": band, "excursion_rms_m": 0.001}));
            has(&e, "stimulus.band_hz", "within 1 to 2000 Hz");
        }
        let e = fields(
            json!({"kind": "noise", "band_hz": [20.0, 200.0], "excursion_rms_m": -1.0,
            "hold": "drive", "steps": [{"from_s": 100.0, "excursion_m": 0.001}]}),
        );
        has(&e, "stimulus.excursion_rms_m", "an RMS displacement >= 0 m");
        has(&e, "stimulus.hold", "sine only");
        has(&e, "stimulus.steps[0].excursion_m", "not a field");
        has(&e, "stimulus.steps[0].excursion_rms_m", "required");
        let e = fields(json!({"excursion_m": 0.002, "band_hz": [20.0, 200.0]}));
        has(&e, "stimulus.band_hz", "not a field of a sine stimulus");
        let e = fields(json!({"kind": "chirp", "excursion_m": 0.002}));
        assert!(e.iter().any(|(f, _)| f.starts_with("stimulus")), "{e:?}");
        let e = fields(json!({"on_s": 1.0, "off_s": 1.0}));
        has(&e, "stimulus.excursion_m", "required");
    }
}
