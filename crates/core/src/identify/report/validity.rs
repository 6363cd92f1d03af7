//! Every headline value with its state (issue 22, decision
//! 0032-trust-headline-validity): `valid`, `extrapolated` (judged outside
//! the measured range beyond a stated margin), `unreliable` (measured, but
//! the measurement or the model behind it failed a check) or
//! `not_determined` (unphysical: the headline field is null and the fit's
//! own number is kept in `fit_value`). Pure.
//!
//! The fits set the states they know of (the small-signal fit its misfit
//! and coherence, the diagnostics their model's); [`judge`] adds what the
//! whole report shows (an unphysical number, a measurement whose noise
//! floor is above [`NOISE_FLOOR_LIMIT_PERCENT`], Keff at a target far
//! outside the measured range). States only ever get worse, so [`judge`]
//! can run again after a field changed (the target of a daemon job).

use super::{LargeSignal, Report, SmallSignal, Stiffness};
use serde::{Deserialize, Serialize};

/// The state of one headline value, from best to worst.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Default,
    Serialize,
    Deserialize,
    utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum State {
    /// Measured, within its stated accuracy (docs/diagnostics.md).
    #[default]
    Valid,
    /// Judged outside the measured range beyond the stated margin.
    Extrapolated,
    /// Measured, but a check of the measurement or its model failed.
    Unreliable,
    /// Unphysical or undefined: the headline field is null (or, for K(x),
    /// must not be used), the fit's number is in `fit_value`.
    NotDetermined,
}

impl State {
    pub fn as_str(self) -> &'static str {
        match self {
            State::Valid => "valid",
            State::Extrapolated => "extrapolated",
            State::Unreliable => "unreliable",
            State::NotDetermined => "not_determined",
        }
    }
}

/// The state of a headline value and why.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct HeadlineValidity {
    pub state: State,
    /// Why the value is not `valid` (one or more sentences, `; `-joined).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The number the fit gave when the headline is `not_determined`: a
    /// diagnostic, never a measured value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit_value: Option<f64>,
}

impl HeadlineValidity {
    /// Moves the state to `state` when that is worse, and adds `reason`
    /// (once).
    pub fn mark(&mut self, state: State, reason: &str) {
        if state > self.state {
            self.state = state;
        }
        if reason.is_empty() {
            return;
        }
        match &mut self.reason {
            Some(r) if r.contains(reason) => {}
            Some(r) => {
                r.push_str("; ");
                r.push_str(reason);
            }
            None => self.reason = Some(reason.to_string()),
        }
    }

    pub fn is_valid(&self) -> bool {
        self.state == State::Valid
    }
}

/// States of the small-signal headline values.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SmallSignalValidity {
    pub f0_hz: HeadlineValidity,
    pub k0_n_per_m: HeadlineValidity,
    pub r_ns_per_m: HeadlineValidity,
    pub q: HeadlineValidity,
}

impl SmallSignalValidity {
    /// Marks every value.
    pub fn mark_all(&mut self, state: State, reason: &str) {
        for v in [
            &mut self.f0_hz,
            &mut self.k0_n_per_m,
            &mut self.r_ns_per_m,
            &mut self.q,
        ] {
            v.mark(state, reason);
        }
    }
}

/// States of the large-signal headline values.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct LargeSignalValidity {
    /// fR (and with it Keff and Ceff at the reached Xpeak).
    pub resonance_hz: HeadlineValidity,
    pub keff_n_per_m: HeadlineValidity,
    /// Keff at the target amplitude, when the report has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keff_at_target_n_per_m: Option<HeadlineValidity>,
}

/// States of the stiffness headline values.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct StiffnessValidity {
    /// K(x) over `valid_range_m` (outside it K(x) is always extrapolated).
    pub k_of_x: HeadlineValidity,
    pub r_ns_per_m: HeadlineValidity,
}

/// Noise floor of the main sweep's force balance (% of RMS(m a)) above
/// which the measurement is not trusted: the large-signal values are
/// `unreliable` and the diagnostics' ladder adds nothing. The default
/// virtual bench and the reference recordings sit at 1.4-1.7 %; a 60 um
/// laser noise (a dark surface) at 8 mm, or a drive limit at 10 % of an
/// 8 mm target, lifts it above 10 % (docs/diagnostics.md, "Bad parts").
pub const NOISE_FLOOR_LIMIT_PERCENT: f64 = 10.0;

/// Model error of a plain analysis, as a share of its noise floor, above
/// which its base model is taken to miss structure (the diagnostics'
/// threshold for unexplained structure, decision 0019).
pub const STRUCTURE_RATIO: f64 = 0.3;

/// The stated accuracy (relative) of a `valid` value (docs/diagnostics.md,
/// "Bad parts"): K(x) RMS over the valid range, R of the main sweep, k0,
/// f0, small-signal R and Q. Keff follows K(x).
pub const ACCURACY_K_OF_X: f64 = 0.01;
pub const ACCURACY_R: f64 = 0.05;
pub const ACCURACY_K0: f64 = 0.03;
pub const ACCURACY_F0: f64 = 0.015;
pub const ACCURACY_SMALL_SIGNAL_R: f64 = 0.10;
pub const ACCURACY_Q: f64 = 0.10;

/// Keff at a target whose excursion reaches beyond the measured range by
/// less than this share of the range's half-span is `valid` (the level
/// control stops near, not at, the target).
pub const TARGET_MARGIN: f64 = 0.02;
/// ... by more than this share, Keff at the target is `not_determined`:
/// the polynomial K(x) is not a measurement that far out.
pub const TARGET_FAR: f64 = 0.5;

/// True for a number above zero (false for NaN).
fn positive(v: f64) -> bool {
    v > 0.0
}

/// Lowest K(x) over the valid range (201 points).
fn k_min_over(k: &[f64], range: [f64; 2]) -> (f64, f64) {
    let mut best = (f64::INFINITY, 0.0);
    for i in 0..=200 {
        let x = range[0] + (range[1] - range[0]) * i as f64 / 200.0;
        let kx = k.iter().rev().fold(0.0, |a, c| a * x + c);
        if kx.is_nan() || kx < best.0 {
            best = (kx, x);
        }
    }
    best
}

/// Null for a headline number that is not determined, its value kept in
/// `fit_value`; a number stays when the state allows it.
fn hide(v: &mut Option<f64>, validity: &mut HeadlineValidity) {
    if validity.state == State::NotDetermined {
        if let Some(x) = v.take() {
            if x.is_finite() {
                validity.fit_value = Some(x);
            }
        }
    }
}

/// The small-signal values' physical checks: k0 > 0 and R > 0, else the
/// value (and what follows from it: f0, Q) is `not_determined`.
pub fn judge_small_signal(s: &mut SmallSignal) {
    let v = &mut s.validity;
    match s.k0_n_per_m {
        Some(k0) if k0 > 0.0 && k0.is_finite() => {}
        Some(k0) => {
            let why = format!("the fit gave k0 = {k0:.4e} N/m <= 0: no physical stiffness");
            v.k0_n_per_m.mark(State::NotDetermined, &why);
            v.f0_hz.mark(State::NotDetermined, &why);
            v.q.mark(State::NotDetermined, &why);
        }
        None => {}
    }
    match s.r_ns_per_m {
        Some(r) if r > 0.0 && r.is_finite() => {}
        Some(r) => {
            let why = format!("the fit gave R = {r:.4e} N s/m <= 0: no physical damping");
            v.r_ns_per_m.mark(State::NotDetermined, &why);
            v.q.mark(State::NotDetermined, &why);
        }
        None => {}
    }
    if s.q.is_none() {
        let why = s
            .q_null_reason
            .clone()
            .unwrap_or_else(|| "Q is undefined".into());
        v.q.mark(State::NotDetermined, &why);
    }
    if v.k0_n_per_m.state == State::NotDetermined {
        hide(&mut s.k0_n_per_m, &mut v.k0_n_per_m);
        hide(&mut s.f0_hz, &mut v.f0_hz);
        s.f0_se_hz = None;
    }
    if v.r_ns_per_m.state == State::NotDetermined {
        hide(&mut s.r_ns_per_m, &mut v.r_ns_per_m);
    }
    if v.q.state == State::NotDetermined {
        let mut q = s.q;
        hide(&mut q, &mut v.q);
        s.q = q;
        s.q_se = None;
    }
}

fn judge_stiffness(s: &mut Stiffness, noise_problem: Option<&str>) {
    let v = &mut s.validity;
    let k = &s.coefficients_n_per_m_pow_i_plus_1;
    if k.is_empty() || k.iter().any(|c| !c.is_finite()) {
        v.k_of_x
            .mark(State::NotDetermined, "no finite K(x) was fitted");
    } else {
        let (kmin, at) = k_min_over(k, s.valid_range_m);
        if !positive(kmin) {
            v.k_of_x.mark(
                State::NotDetermined,
                &format!(
                    "the fitted K(x) reaches {kmin:.4e} N/m <= 0 at x = {:.3} mm inside the measured range: no physical stiffness",
                    at * 1e3
                ),
            );
        }
    }
    if !positive(s.r_ns_per_m) {
        v.r_ns_per_m.mark(
            State::NotDetermined,
            &format!(
                "the fit gave R = {:.4e} N s/m <= 0: no physical damping",
                s.r_ns_per_m
            ),
        );
        v.r_ns_per_m.fit_value = Some(s.r_ns_per_m).filter(|r| r.is_finite());
    }
    if let Some(p) = noise_problem {
        v.k_of_x.mark(State::Unreliable, p);
        v.r_ns_per_m.mark(State::Unreliable, p);
    }
}

fn judge_large_signal(l: &mut LargeSignal, s: &Stiffness, noise_problem: Option<&str>) {
    if let Some(p) = noise_problem {
        l.validity.resonance_hz.mark(State::Unreliable, p);
        l.validity.keff_n_per_m.mark(State::Unreliable, p);
    }
    if l.keff_method.as_deref() == Some("chosen_model") {
        // Keff of the chosen model's K(x): as good as that K(x).
        let k = &s.validity.k_of_x;
        if !k.is_valid() {
            let why = format!(
                "Keff is the chosen model's K(x) over the excursion, which is {}",
                k.state.as_str()
            );
            let st = k.state.max(State::Unreliable);
            l.validity.resonance_hz.mark(st, &why);
            l.validity.keff_n_per_m.mark(st, &why);
        }
    }
    let Some(xt) = l.target_xpeak_m.filter(|x| x.is_finite() && *x > 0.0) else {
        return;
    };
    let mut v = l.validity.keff_at_target_n_per_m.take().unwrap_or_default();
    let [lo, hi] = s.valid_range_m;
    let c = 0.5 * (l.x_min_at_resonance_m + l.x_max_at_resonance_m);
    let c = if c.is_finite() { c } else { 0.0 };
    let half = 0.5 * (hi - lo);
    let beyond = ((c + xt) - hi).max(lo - (c - xt)).max(0.0);
    let share = if half > 0.0 {
        beyond / half
    } else {
        f64::INFINITY
    };
    let what = format!(
        "Keff at the target {:.3} mm is judged over {:.3} .. {:.3} mm, {:.0} % of the measured range's half-span beyond it ({:.3} .. {:.3} mm)",
        xt * 1e3,
        (c - xt) * 1e3,
        (c + xt) * 1e3,
        100.0 * share,
        lo * 1e3,
        hi * 1e3
    );
    if share > TARGET_FAR {
        v.mark(
            State::NotDetermined,
            &format!(
                "{what}: more than {:.0} %, the polynomial K(x) is no measurement there; measure at a level that reaches the target",
                100.0 * TARGET_FAR
            ),
        );
    } else if share > TARGET_MARGIN {
        v.mark(State::Extrapolated, &what);
    }
    if !s.validity.k_of_x.is_valid() {
        let st = s.validity.k_of_x.state.max(State::Unreliable);
        v.mark(
            st,
            &format!("K(x) behind it is {}", s.validity.k_of_x.state.as_str()),
        );
    }
    let mut value = l.keff_at_target_n_per_m;
    if let Some(x) = value.filter(|x| !positive(*x)) {
        v.mark(
            State::NotDetermined,
            &format!("Keff at the target from K(x) is {x:.4e} N/m <= 0"),
        );
    }
    hide(&mut value, &mut v);
    l.keff_at_target_n_per_m = value;
    l.validity.keff_at_target_n_per_m = Some(v);
}

/// The measurement's own problem, when its noise floor is above
/// [`NOISE_FLOOR_LIMIT_PERCENT`] (None otherwise).
pub fn noise_problem(noise_floor_percent: f64) -> Option<String> {
    (noise_floor_percent.is_nan() || noise_floor_percent > NOISE_FLOOR_LIMIT_PERCENT).then(|| {
        format!(
            "the measurement's noise floor is {noise_floor_percent:.1} % of the inertia force (> {NOISE_FLOOR_LIMIT_PERCENT:.0} %): too little excursion for the sensor noise (drive limit, dark surface)"
        )
    })
}

/// Marks the main sweep's values (K(x), R, fR, Keff) `unreliable` for `why`.
fn mark_main_sweep(r: &mut Report, why: &str) {
    let s = &mut r.stiffness.validity;
    s.k_of_x.mark(State::Unreliable, why);
    s.r_ns_per_m.mark(State::Unreliable, why);
    let l = &mut r.large_signal.validity;
    l.resonance_hz.mark(State::Unreliable, why);
    l.keff_n_per_m.mark(State::Unreliable, why);
}

/// Adds the report-level states to every headline value (idempotent:
/// states only get worse; a hidden number stays hidden).
pub fn judge(r: &mut Report) {
    let noise = noise_problem(r.model.noise_floor_percent);
    if let Some(s) = r.small_signal.as_mut() {
        judge_small_signal(s);
    }
    judge_stiffness(&mut r.stiffness, noise.as_deref());
    let stiffness = r.stiffness.clone();
    judge_large_signal(&mut r.large_signal, &stiffness, noise.as_deref());
}

/// The plain analysis (no effects, no diagnostics): structure its base
/// model leaves makes K(x), R, the resonance and the small-signal values
/// unreliable (an effect the diagnostics would find: creep, friction, a
/// second mode; the linear resonator of the pre-measurement does not hold
/// it either: creep put k0 10-12 % high on the virtual bench with a
/// misfit below 10 %). Called by [`super::analyze`], not by the
/// diagnostics, which judge their own model.
///
/// `creep`: why the small-signal fit's whole band points to creep (its
/// corner in the band); the part creeps in the main sweep as well, which
/// the base model cannot hold either (K(x) 7-10 % high on the virtual
/// bench, R 16-27 % high, with a model error below the structure ratio).
pub fn judge_plain(r: &mut Report, creep: Option<&str>) {
    if let Some(c) = creep {
        let why =
            format!("the pre-measurement points to creep, which the base model does not hold: {c}");
        mark_main_sweep(r, &why);
    }
    let m = &r.model;
    if m.effects.is_empty() && m.model_error_percent > STRUCTURE_RATIO * m.noise_floor_percent {
        let why = format!(
            "the base model leaves structure (model error {:.2} % over a noise floor of {:.2} %): an effect outside it biases the fit; the diagnostics (--diagnose) tell which",
            m.model_error_percent, m.noise_floor_percent
        );
        mark_main_sweep(r, &why);
        if let Some(ss) = r.small_signal.as_mut() {
            ss.validity.mark_all(State::Unreliable, &why);
        }
    }
    judge(r);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marks_only_get_worse_and_reasons_are_kept_once() {
        let mut v = HeadlineValidity::default();
        v.mark(State::Unreliable, "a");
        v.mark(State::Extrapolated, "b");
        v.mark(State::Unreliable, "a");
        assert_eq!(v.state, State::Unreliable);
        assert_eq!(v.reason.as_deref(), Some("a; b"));
        let j = serde_json::to_value(&v).unwrap();
        assert_eq!(
            j,
            serde_json::json!({"state": "unreliable", "reason": "a; b"})
        );
        assert_eq!(
            serde_json::to_value(HeadlineValidity::default()).unwrap(),
            serde_json::json!({"state": "valid"})
        );
    }
}
