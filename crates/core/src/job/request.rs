//! The job request as a client sends it (`POST /api/v1/jobs`): its shape is
//! this struct (serde refuses unknown members; the API schema derives from
//! it), and [`JobRequest::validate`] checks what serde cannot express: ranges
//! with units, cross-field rules, a bench's limits, physically meaningless
//! values.

use super::parse::{check_chars, FieldError};
use super::spec::{
    production_part, Admission, BenchOffer, JobPart, JobProduction, JobSpec, Limits, ProcedureMode,
    Purpose,
};
use super::{
    valid_serial, MAX_LEVELS, MAX_ORDER, MAX_REPEATS, MIN_MOVING_MASS_KG, MIN_TARGET_XPEAK_M,
    SERIAL_RULE,
};
use crate::identify::Method;
use crate::physics::PartSpec;
use serde::{Deserialize, Serialize};

/// Tighter limits than the bench's.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JobLimits {
    /// At most the bench's (m).
    pub max_displacement_m: Option<f64>,
    /// At most the bench's (V).
    pub max_drive_v: Option<f64>,
}

/// `POST /api/v1/jobs`: a measurement job. Defaults come from the bench and
/// the recipe; `springbench_core::job::JobRequest::validate` checks every field.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JobRequest {
    pub part: JobPart,
    /// Bench id (default: the first bench).
    pub bench: Option<String>,
    /// Higher runs first (default 0; -1000..1000).
    #[schema(minimum = -1000, maximum = 1000)]
    pub priority: Option<i64>,
    /// Target peak displacement (m); or `levels_m` for a level series.
    pub target_xpeak_m: Option<f64>,
    /// 1 to 16 target peak displacements (m).
    pub levels_m: Option<Vec<f64>>,
    /// `two-signal` (default) or `one-signal`.
    pub method: Option<Method>,
    /// Order of K(x) (1-12; chosen from the data when absent).
    #[schema(minimum = 1, maximum = 12)]
    pub order: Option<usize>,
    /// Measurements per level (1-10).
    #[schema(minimum = 1, maximum = 10)]
    pub repeats: Option<u32>,
    pub moving_mass_kg: Option<f64>,
    /// Virtual bench: a preset name (`presets/*.toml`).
    pub preset: Option<String>,
    /// Virtual bench: the part's parameters in full (`physics::PartSpec`).
    #[schema(value_type = Option<Object>)]
    pub part_spec: Option<PartSpec>,
    /// Virtual bench: one part of a production lot.
    pub production: Option<JobProduction>,
    /// QC recipe name: its newest version's procedure settings are filled in and the job ends with a verdict.
    pub recipe: Option<String>,
    /// `full` or `production` (needs a recipe; its golden units' reference
    /// paces the short procedure); default: the recipe's `procedure.mode`,
    /// else `full`. A gauge study runs both on the same parts.
    pub procedure: Option<ProcedureMode>,
    /// Tighter limits than the bench's.
    pub limits: Option<JobLimits>,
    /// Why the part is measured: `production`, `golden_unit`,
    /// `bench_calibration`, `gauge_study`, `repeat` or `engineering`. SPC,
    /// yield and the shift counters count `production` only. Default:
    /// `production` with a recipe, else `engineering` (decision 0100).
    pub purpose: Option<Purpose>,
}

/// A limit of the job: the bench's, or a tighter one given in `field` (`unit`).
fn tighter(
    given: Option<f64>,
    bench: f64,
    field: &str,
    unit: &str,
    errors: &mut Vec<FieldError>,
) -> f64 {
    match given {
        None => bench,
        Some(x) if x > 0.0 && x <= bench => x,
        Some(x) => {
            errors.push(FieldError::new(
                field,
                format!("must be in (0, {bench}] {unit} (the bench's limit), got {x}"),
            ));
            bench
        }
    }
}

impl JobRequest {
    /// A job body checked whole: every bad member and every bad value named
    /// in one answer. `parsed` is [`super::parse_lenient`]'s answer; `recipe`
    /// fills in a recipe's procedure settings between parsing and the checks.
    pub fn check(
        parsed: (Option<JobRequest>, Vec<FieldError>),
        adm: &Admission,
        recipe: impl FnOnce(&mut JobRequest) -> Result<(), Vec<FieldError>>,
    ) -> Result<JobSpec, Vec<FieldError>> {
        let (req, mut errors) = parsed;
        let Some(mut req) = req else {
            return Err(errors);
        };
        if let Err(e) = recipe(&mut req) {
            errors.extend(e);
            return Err(errors);
        }
        match req.validate(adm) {
            Ok(spec) if errors.is_empty() => Ok(spec),
            Ok(_) => Err(errors),
            Err(more) => {
                for m in more {
                    if !errors.iter().any(|e| e.field == m.field) {
                        errors.push(m);
                    }
                }
                Err(errors)
            }
        }
    }

    /// Checks the request against the station's benches and defaults; the
    /// accepted job has every default filled in. One message per bad field.
    pub fn validate(self, adm: &Admission) -> Result<JobSpec, Vec<FieldError>> {
        let mut errors = Vec::new();
        let e = &mut errors;
        if !valid_serial(&self.part.serial) {
            e.push(FieldError::new("part.serial", SERIAL_RULE));
        }
        check_chars(self.part.kind.as_deref(), "part.kind", 64, e);
        check_chars(self.part.notes.as_deref(), "part.notes", 4096, e);

        let bench: Option<&BenchOffer> = match &self.bench {
            None => adm.benches.first(),
            Some(id) => {
                let b = adm.benches.iter().find(|b| &b.id == id);
                if b.is_none() {
                    let ids: Vec<_> = adm.benches.iter().map(|b| b.id.as_str()).collect();
                    e.push(FieldError::new(
                        "bench",
                        format!("unknown bench '{id}' (benches: {})", ids.join(", ")),
                    ));
                }
                b
            }
        };
        if bench.is_none() && self.bench.is_none() {
            e.push(FieldError::new("bench", "this station has no bench"));
        }

        // limits: the bench's, or tighter
        let limits = bench.map(|b| {
            let l = self.limits.unwrap_or_default();
            Limits {
                max_displacement_m: tighter(
                    l.max_displacement_m,
                    b.limits.max_displacement_m,
                    "limits.max_displacement_m",
                    "m",
                    e,
                ),
                max_drive_v: tighter(
                    l.max_drive_v,
                    b.limits.max_drive_v,
                    "limits.max_drive_v",
                    "V",
                    e,
                ),
            }
        });

        // levels
        let levels: Vec<(String, f64)> = match (self.target_xpeak_m, &self.levels_m) {
            (Some(_), Some(_)) => {
                e.push(FieldError::new(
                    "levels_m",
                    "give either target_xpeak_m or levels_m, not both",
                ));
                vec![]
            }
            (Some(x), None) => vec![("target_xpeak_m".to_string(), x)],
            (None, Some(a)) => {
                if a.is_empty() || a.len() > MAX_LEVELS {
                    e.push(FieldError::new(
                        "levels_m",
                        format!("give 1 to {MAX_LEVELS} target peak displacements"),
                    ));
                }
                a.iter()
                    .enumerate()
                    .map(|(i, x)| (format!("levels_m[{i}]"), *x))
                    .collect()
            }
            (None, None) => vec![("target_xpeak_m".to_string(), adm.target_xpeak_m)],
        };
        for (i, (f, x)) in levels.iter().enumerate() {
            // (JSON numbers are finite: no NaN reaches here)
            if i > 0 && *x <= levels[i - 1].1 {
                e.push(FieldError::new(
                    f,
                    format!(
                        "levels must rise strictly: {x} m after {} m",
                        levels[i - 1].1
                    ),
                ));
            } else if *x < MIN_TARGET_XPEAK_M {
                e.push(FieldError::new(
                    f,
                    format!(
                        "must be at least {MIN_TARGET_XPEAK_M} m (10 µm; below it the sweep measures laser noise), got {x} m"
                    ),
                ));
            } else if let Some(l) = limits {
                if *x > l.max_displacement_m {
                    e.push(FieldError::new(
                        f,
                        format!(
                            "{x} m is beyond the displacement limit of {} m",
                            l.max_displacement_m
                        ),
                    ));
                }
            }
        }

        let order = match self.order {
            None => adm.order,
            Some(n) if (1..=MAX_ORDER).contains(&n) => Some(n),
            Some(_) => {
                e.push(FieldError::new(
                    "order",
                    format!("must be an integer from 1 to {MAX_ORDER}"),
                ));
                None
            }
        };
        let repeats = match self.repeats {
            None => 1,
            Some(n) if (1..=MAX_REPEATS).contains(&n) => n,
            Some(_) => {
                e.push(FieldError::new(
                    "repeats",
                    format!("must be an integer from 1 to {MAX_REPEATS}"),
                ));
                1
            }
        };
        let priority = match self.priority {
            None => 0,
            Some(n) if (-1000..=1000).contains(&n) => n,
            Some(_) => {
                e.push(FieldError::new(
                    "priority",
                    "must be an integer from -1000 to 1000",
                ));
                0
            }
        };

        // the part mounted on the virtual bench
        if let Some(name) = &self.preset {
            if crate::physics::preset(name).is_err() {
                e.push(FieldError::new(
                    "preset",
                    format!(
                        "unknown preset '{name}' (presets: {})",
                        crate::physics::preset_names().join(", ")
                    ),
                ));
            }
        }
        if let Some(p) = &self.part_spec {
            if self.preset.is_some() {
                e.push(FieldError::new(
                    "part_spec",
                    "give either preset or part_spec, not both",
                ));
            }
            if let Err(m) = p.validate() {
                e.push(FieldError::new("part_spec", m));
            }
        }
        if let Some(p) = &self.production {
            if self.preset.is_some() || self.part_spec.is_some() {
                e.push(FieldError::new(
                    "production",
                    "give one of preset, part_spec and production",
                ));
            }
            if let Err(m) = production_part(p) {
                e.push(FieldError::new("production.preset", m));
            }
        }
        if let Some(r) = &self.recipe {
            if !valid_serial(r) {
                e.push(FieldError::new("recipe", "must be a recipe name"));
            }
        }
        if self.procedure == Some(ProcedureMode::Production) && self.recipe.is_none() {
            e.push(FieldError::new(
                "procedure",
                "production needs a recipe: its golden units tell the resonances and drive levels",
            ));
        }

        let moving_mass_kg = match self.moving_mass_kg {
            // On the virtual bench it defaults to the mounted part's.
            None => {
                let mounted = if let Some(p) = &self.part_spec {
                    Ok(p.clone())
                } else if let Some(p) = &self.production {
                    production_part(p)
                } else if let Some(name) = &self.preset {
                    crate::physics::preset(name)
                } else if let Some(b) = bench {
                    crate::physics::preset(&b.preset)
                } else {
                    Err(String::new())
                };
                match mounted {
                    Ok(p) => Some(p.moving_mass_kg),
                    Err(m)
                        if self.preset.is_none()
                            && self.part_spec.is_none()
                            && self.production.is_none()
                            && bench.is_some() =>
                    {
                        e.push(FieldError::new(
                            "moving_mass_kg",
                            format!("required: the mounted part's mass is not known ({m})"),
                        ));
                        None
                    }
                    Err(_) => None,
                }
            }
            Some(m) if (MIN_MOVING_MASS_KG..=10.0).contains(&m) => Some(m),
            Some(m) => {
                e.push(FieldError::new(
                    "moving_mass_kg",
                    format!("must be in [{MIN_MOVING_MASS_KG}, 10] kg, got {m} kg"),
                ));
                None
            }
        };

        if !errors.is_empty() {
            return Err(errors);
        }
        match (bench, limits, moving_mass_kg) {
            (Some(bench), Some(limits), Some(moving_mass_kg)) => Ok(JobSpec {
                part: self.part,
                bench: bench.id.clone(),
                moving_mass_kg,
                levels_m: levels.into_iter().map(|(_, x)| x).collect(),
                method: self.method.unwrap_or(adm.method),
                order,
                repeats,
                procedure: self.procedure.unwrap_or_default(),
                priority,
                preset: self.preset,
                part_spec: self.part_spec,
                limits,
                recipe: None,
                production: self.production,
                submitted_by: None,
                purpose: self.purpose.unwrap_or(if self.recipe.is_some() {
                    Purpose::Production
                } else {
                    Purpose::Engineering
                }),
            }),
            _ => Err(vec![FieldError::new("", "invalid job")]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{json, Value};

    fn adm() -> Admission {
        Admission {
            benches: vec![BenchOffer {
                id: "virtual-1".into(),
                limits: Limits {
                    max_displacement_m: 0.01,
                    max_drive_v: 10.0,
                },
                preset: "spider_4in".into(),
            }],
            target_xpeak_m: 0.004,
            method: Method::TwoSignal,
            order: None,
        }
    }

    fn check(body: Value) -> Result<JobSpec, Vec<FieldError>> {
        JobRequest::check(super::super::parse_lenient(&body), &adm(), |_| Ok(()))
    }

    fn fields(e: &[FieldError]) -> Vec<&str> {
        e.iter().map(|e| e.field.as_str()).collect()
    }

    #[test]
    fn the_procedure_is_full_unless_named_and_production_needs_a_recipe() {
        let j = check(json!({"part": {"serial": "SN-1"}})).unwrap();
        assert_eq!(j.procedure, ProcedureMode::Full);
        // full is the default and is not written: jobs stored before read back the same
        assert!(serde_json::to_value(&j).unwrap().get("procedure").is_none());
        let e = check(json!({"part": {"serial": "SN-1"}, "procedure": "production"})).unwrap_err();
        assert_eq!(fields(&e), ["procedure"]);
        let j = check(
            json!({"part": {"serial": "SN-1"}, "procedure": "production",
                             "recipe": "spider-4in"}),
        )
        .unwrap();
        assert_eq!(j.procedure, ProcedureMode::Production);
        let e = check(json!({"part": {"serial": "SN-1"}, "procedure": "fast"})).unwrap_err();
        assert_eq!(fields(&e), ["procedure"]);
    }

    #[test]
    fn minimal_job_takes_the_defaults() {
        let j = check(json!({"part": {"serial": "SN-1"}, "moving_mass_kg": 0.02})).unwrap();
        assert_eq!(j.bench, "virtual-1");
        assert_eq!(j.levels_m, vec![0.004]);
        assert_eq!(j.repeats, 1);
        assert_eq!(j.limits, adm().benches[0].limits);
        assert_eq!(j.moving_mass_kg, 0.02);
        // The accepted job reads back unchanged.
        let back: JobSpec = serde_json::from_value(serde_json::to_value(&j).unwrap()).unwrap();
        assert_eq!(back, j);
        // the mounted preset's mass when none is given
        let j = check(json!({"part": {"serial": "SN-1"}})).unwrap();
        let preset = crate::physics::preset("spider_4in").unwrap();
        assert_eq!(j.moving_mass_kg, preset.moving_mass_kg);
    }

    #[test]
    fn every_bad_field_gets_its_own_message() {
        let e = check(
            json!({"part": {"serial": "a/b", "colour": 1}, "moving_mass_kg": -1.0,
                    "levels_m": [0.004, 0.5, "x"], "method": "three-signal", "order": 0,
                    "repeats": 100, "bench": "nope", "extra": true}),
        )
        .unwrap_err();
        let f = fields(&e);
        // shape errors first (the members at fault dropped), then the rest
        for want in [
            "extra",
            "part.colour",
            "part.serial",
            "bench",
            "levels_m[2]",
            "method",
            "order",
            "repeats",
            "moving_mass_kg",
        ] {
            assert!(f.contains(&want), "{want} missing in {f:?}");
        }
        let e = check(json!({"part": {"serial": "S"}, "moving_mass_kg": 0.0,
                             "levels_m": [0.004, 0.5], "method": "three-signal",
                             "preset": "no-such-part", "wat": 1}))
        .unwrap_err();
        let f = fields(&e);
        for want in ["wat", "moving_mass_kg", "levels_m[1]", "method", "preset"] {
            assert!(f.contains(&want), "{want} missing in {f:?}");
        }
    }

    #[test]
    fn limits_may_only_be_tightened() {
        let mut b = json!({"part": {"serial": "S"}, "moving_mass_kg": 0.02});
        b["limits"] = json!({"max_displacement_m": 0.02});
        let e = check(b.clone()).unwrap_err();
        assert_eq!(fields(&e), ["limits.max_displacement_m"]);
        b["limits"] = json!({"max_displacement_m": 0.005});
        b["target_xpeak_m"] = json!(0.006);
        let e = check(b.clone()).unwrap_err();
        assert_eq!(fields(&e), ["target_xpeak_m"]);
        b["target_xpeak_m"] = json!(0.004);
        let j = check(b).unwrap();
        assert_eq!(j.limits.max_displacement_m, 0.005);
        assert_eq!(j.limits.max_drive_v, 10.0);
    }

    #[test]
    fn physically_meaningless_values_are_refused_with_their_unit() {
        for (body, field) in [
            (
                json!({"part": {"serial": "S"}, "target_xpeak_m": 1e-300}),
                "target_xpeak_m",
            ),
            (
                json!({"part": {"serial": "S"}, "target_xpeak_m": 0.0}),
                "target_xpeak_m",
            ),
            (
                json!({"part": {"serial": "S"}, "levels_m": [0.004, 5e-6]}),
                "levels_m[1]",
            ),
            (
                json!({"part": {"serial": "S"}, "moving_mass_kg": 1e-300}),
                "moving_mass_kg",
            ),
        ] {
            let e = check(body.clone()).unwrap_err();
            assert_eq!(fields(&e), [field], "{body}");
            assert!(
                e[0].message.contains(" m") || e[0].message.contains(" kg"),
                "{}",
                e[0].message
            );
        }
        // the smallest target accepted
        assert!(
            check(json!({"part": {"serial": "S"}, "target_xpeak_m": MIN_TARGET_XPEAK_M})).is_ok()
        );
    }

    #[test]
    fn levels_must_rise_strictly() {
        // as a recipe's levels must (qc::recipe): a repeated or falling
        // level is a typo, not a series
        for (levels, field) in [
            (json!([0.004, 0.004]), "levels_m[1]"),
            (json!([0.008, 0.004]), "levels_m[1]"),
            (json!([0.002, 0.006, 0.005]), "levels_m[2]"),
        ] {
            let e = check(json!({"part": {"serial": "S"}, "levels_m": levels})).unwrap_err();
            assert_eq!(fields(&e), [field], "{levels}");
            assert!(e[0].message.contains("m"), "{}", e[0].message);
        }
        assert!(check(json!({"part": {"serial": "S"}, "levels_m": [0.002, 0.004]})).is_ok());
    }

    #[test]
    fn non_object_bodies_and_wrong_types_are_refused() {
        assert_eq!(fields(&check(json!([1])).unwrap_err()), [""]);
        let e = check(json!({"moving_mass_kg": 0.02})).unwrap_err();
        assert_eq!(fields(&e), ["part"]);
        let e = check(json!({"part": {"serial": "S"}, "moving_mass_kg": "heavy"})).unwrap_err();
        assert_eq!(fields(&e), ["moving_mass_kg"]);
        // null is absent, for every optional member
        let j = check(json!({"part": {"serial": "S", "kind": null}, "bench": null,
                             "method": null, "limits": null, "moving_mass_kg": 0.02}))
        .unwrap();
        assert_eq!(j.bench, "virtual-1");
    }
}
