//! The material's memory against its neighbours (issue 33, decision 0120):
//! hysteresis against Coulomb friction and creep, reversible softening
//! against stiffness drift and creep. One sweep moves excursion, frequency
//! and time together, so a neighbour may explain much of the same structure;
//! the diagnostics then either show that the data name one of the two (each
//! tested once the other is in the model), or say they cannot tell and name
//! the experiment that would. Never the neighbour with confidence when the
//! data do not separate them.

use super::engine::{self, CandidateResult, EngineOptions, EngineResult, Term};
use crate::effects::EffectId;
use crate::identify::diagnostics::Ambiguity;
use crate::identify::ForceBalanceData;

/// The confusable pairs: a memory effect and a neighbour.
pub const PAIRS: [(EffectId, EffectId); 4] = [
    (EffectId::Hysteresis, EffectId::CoulombFriction),
    (EffectId::Hysteresis, EffectId::Creep),
    (EffectId::ReversibleSoftening, EffectId::StiffnessDrift),
    (EffectId::ReversibleSoftening, EffectId::Creep),
];

/// A neighbour is checked when it removes at least this share of the
/// chosen effect's held-out model error (against the base model): below
/// it, the neighbour explains too little of the same structure to be
/// mistaken for it.
pub const OVERLAP: f64 = 1.0 / 3.0;

/// What the data say about one pair.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// The chosen effect stays significant with the other in the model, the
    /// other is not significant with the chosen one in: the data name the
    /// chosen one; the other only stood in for it.
    Named,
    /// Neither is needed once the other is in (or only the other is): this
    /// data cannot tell them apart.
    CannotTell,
}

/// One pair checked: `chosen` is in the final model, `other` is a
/// significant candidate against the base model that is not.
#[derive(Debug, Clone, PartialEq)]
pub struct PairCheck {
    pub chosen: EffectId,
    pub other: EffectId,
    /// Share of the base model's held-out model error each removes (%).
    pub error_reduction_percent: [f64; 2],
    /// Their variance inflation against the base model.
    pub variance_inflation: [f64; 2],
    /// Both beyond the identifiability limit: not told apart by the tests.
    pub both_collinear: bool,
    /// The chosen effect ranked against the final model with `other` in its place.
    pub chosen_after_other: Option<CandidateResult>,
    /// `other` ranked against the final model.
    pub other_after_chosen: Option<CandidateResult>,
    pub outcome: Outcome,
}

impl PairCheck {
    /// The memory effect of the pair.
    pub fn memory(&self) -> EffectId {
        if matches!(
            self.chosen,
            EffectId::Hysteresis | EffectId::ReversibleSoftening
        ) {
            self.chosen
        } else {
            self.other
        }
    }

    /// The experiment that separates the pair: the memory effect's own.
    pub fn separating_experiment(&self) -> &'static str {
        Term::Effect(self.memory()).separating_experiment()
    }

    fn p(c: &Option<CandidateResult>) -> String {
        c.as_ref()
            .map_or("not fitted".into(), |c| format!("p {:.2e}", c.p_value))
    }

    /// One sentence for the document.
    pub fn note(&self) -> String {
        let (a, b) = (self.chosen.as_str(), self.other.as_str());
        match self.outcome {
            Outcome::Named => format!(
                "{b} only stood in for {a}: it removes {:.0} % of the base model's error alone, but is not significant once {a} is in ({}), while {a} stays significant with {b} in its place ({}); the data name {a}",
                self.error_reduction_percent[1],
                Self::p(&self.other_after_chosen),
                Self::p(&self.chosen_after_other)
            ),
            Outcome::CannotTell => format!(
                "cannot tell {a} from {b} with this data: they remove {:.0} % and {:.0} % of the base model's error{}; the model holds {a}, but {b} may be what the part has; to separate them: {}",
                self.error_reduction_percent[0],
                self.error_reduction_percent[1],
                if self.both_collinear {
                    format!(", and both are mostly a stiffness in this sweep (variance inflation {:.0} and {:.0}), so what tells them apart is too small to trust", self.variance_inflation[0], self.variance_inflation[1])
                } else {
                    format!(", and {a} is {} once {b} is in ({})", if self.chosen_after_other.as_ref().is_some_and(|c| c.significant) { "significant" } else { "not significant" }, Self::p(&self.chosen_after_other))
                },
                self.separating_experiment()
            ),
        }
    }
}

/// Checks every confusable pair of which one member is in the final model
/// of `r` and the other is a plausible significant candidate against the
/// base model that removes at least [`OVERLAP`] of the chosen one's error.
pub fn check(d: &ForceBalanceData, r: &EngineResult, opts: &EngineOptions) -> Vec<PairCheck> {
    let mut out = Vec::new();
    let find = |e: EffectId| r.candidates.iter().find(|c| c.effect == e.as_str());
    let in_model = |e: EffectId| r.model.effect_ids.contains(&e);
    // The other candidates ranked against the final model (one run).
    let mut against_final: Option<Vec<CandidateResult>> = None;
    for (m, n) in PAIRS {
        let (chosen, other) = match (in_model(m), in_model(n)) {
            (true, false) => (m, n),
            (false, true) => (n, m),
            _ => continue,
        };
        let (Some(c), Some(o)) = (find(chosen), find(other)) else {
            continue;
        };
        if !o.significant
            || o.not_added.is_some()
            || o.error_reduction_percent < OVERLAP * c.error_reduction_percent
        {
            continue;
        }
        let ranked = against_final.get_or_insert_with(|| {
            engine::run(
                d,
                &EngineOptions {
                    forced: r.model.effect_ids.clone(),
                    ladder: false,
                    order: Some(r.model.order),
                    ..opts.clone()
                },
            )
            .map(|s| s.candidates)
            .unwrap_or_default()
        });
        let other_after_chosen = ranked.iter().find(|c| c.effect == other.as_str()).cloned();
        // The final model with the other in the chosen one's place.
        let mut forced: Vec<EffectId> = r
            .model
            .effect_ids
            .iter()
            .copied()
            .filter(|e| *e != chosen)
            .collect();
        forced.push(other);
        let chosen_after_other = engine::run(
            d,
            &EngineOptions {
                forced,
                ladder: false,
                order: Some(r.model.order),
                ..opts.clone()
            },
        )
        .ok()
        .and_then(|s| {
            s.candidates
                .into_iter()
                .find(|c| c.effect == chosen.as_str())
        });
        let sig = |c: &Option<CandidateResult>| c.as_ref().is_some_and(|c| c.significant);
        // Both mostly a stiffness in this sweep (each collinear with the
        // model beyond the identifiability limit): what tells them apart is
        // a small remainder of each, and a test on it is not trusted
        // (hysteresis with a yield excursion far beyond the sweep's against
        // creep with a long tau: a thin loop each).
        let both_collinear = !c.identifiable && !o.identifiable;
        let outcome = if both_collinear {
            Outcome::CannotTell
        } else if sig(&chosen_after_other) && !sig(&other_after_chosen) {
            Outcome::Named
        } else if sig(&chosen_after_other) && sig(&other_after_chosen) {
            // Both needed: each holds its own share (the ladder left the
            // other out for its plausibility or stability); not a confusion.
            continue;
        } else {
            Outcome::CannotTell
        };
        out.push(PairCheck {
            chosen,
            other,
            error_reduction_percent: [c.error_reduction_percent, o.error_reduction_percent],
            variance_inflation: [c.variance_inflation, o.variance_inflation],
            both_collinear,
            chosen_after_other,
            other_after_chosen,
            outcome,
        });
    }
    out
}

/// Writes the checks into the document: a candidate that only stood in
/// gets `stands_in_for` and the note and ranks below the one it stood in
/// for; a pair the data cannot tell apart becomes an ambiguity (replacing
/// the swap test's for the same pair) and a warning (returned).
pub fn apply(
    pairs: &[PairCheck],
    candidates: &mut [CandidateResult],
    ambiguities: &mut Vec<Ambiguity>,
) -> Vec<String> {
    let mut warnings = Vec::new();
    for pc in pairs {
        let (a, b) = (
            pc.chosen.as_str().to_string(),
            pc.other.as_str().to_string(),
        );
        match pc.outcome {
            Outcome::Named => {
                if let Some(c) = candidates.iter_mut().find(|c| c.effect == b) {
                    c.stands_in_for = Some(a);
                    c.note = Some(pc.note());
                }
            }
            Outcome::CannotTell => {
                warnings.push(pc.note());
                ambiguities.retain(|x| !(x.effects.contains(&a) && x.effects.contains(&b)));
                ambiguities.push(Ambiguity {
                    effects: [a, b],
                    error_reduction_percent: pc.error_reduction_percent,
                    p_value_of_first_after_second: pc
                        .chosen_after_other
                        .as_ref()
                        .map(|c| c.p_value),
                    separating_experiment: pc.separating_experiment().to_string(),
                    note: pc.note(),
                });
            }
        }
    }
    // Significant first, a stand-in below the others, then by held-out error.
    candidates.sort_by(|a, b| {
        b.significant
            .cmp(&a.significant)
            .then(a.stands_in_for.is_some().cmp(&b.stands_in_for.is_some()))
            .then(a.cv_sse.total_cmp(&b.cv_sse))
    });
    warnings
}
