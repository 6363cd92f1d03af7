//! The job request: validated at enqueue, stored as accepted (defaults filled
//! in), read back by the runner. Validation collects one message per bad field
//! (the API turns them into a 422 problem document).

use crate::bench::Limits;
use crate::config::{BenchConfig, Config};
use crate::identify::Method;
use crate::physics::PartSpec;
use serde::{Deserialize, Serialize};
use serde_json::Value;

pub use crate::job::{
    valid_serial, MAX_LEVELS, MAX_ORDER, MAX_REPEATS, MIN_MOVING_MASS_KG, SERIAL_RULE,
};

/// The part a job measures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartRef {
    pub serial: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notes: Option<String>,
}

/// A job as accepted: every default filled in, everything checked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobSpec {
    pub part: PartRef,
    /// Bench that runs the job.
    pub bench: String,
    /// Moving mass of part plus inner clamp (kg).
    pub moving_mass_kg: f64,
    /// Target peak displacement of each narrow sweep (m): one measurement per level and repeat.
    pub levels_m: Vec<f64>,
    pub method: Method,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub order: Option<usize>,
    /// How often the whole procedure runs.
    pub repeats: u32,
    /// Higher runs first; equal priorities run in submission order.
    pub priority: i64,
    /// Virtual bench: the preset mounted (when `part_spec` is absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// Virtual bench: the physical parameters of the part mounted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part_spec: Option<PartSpec>,
    /// Limits of this job (the bench's, or tighter).
    pub limits: Limits,
    /// The QC recipe (version and hash) the job runs and is judged by.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recipe: Option<RecipeRef>,
    /// Virtual bench: a part of a production lot (preset with manufacturing spread).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub production: Option<ProductionPart>,
    /// Name of the token that submitted the job (traceability); None with open access.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub submitted_by: Option<String>,
}

/// The recipe version a job runs (`"recipe": NAME` in the request; filled in at submission).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecipeRef {
    pub name: String,
    pub version: i64,
    pub sha256: String,
}

/// A part of a production lot on the virtual bench: the nominal `preset`
/// with the lot's spread drawn from `seed`, and an optional defect.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProductionPart {
    pub preset: String,
    pub seed: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub defect: Option<crate::physics::production::Defect>,
}

/// One message per bad field (`field` is a JSON path like `levels_m[1]`).
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct FieldError {
    pub field: String,
    pub message: String,
}

fn err(field: &str, message: impl Into<String>) -> FieldError {
    FieldError {
        field: field.to_string(),
        message: message.into(),
    }
}

/// The members a job body may have (anything else is refused).
pub const FIELDS: &[&str] = &[
    "part",
    "bench",
    "moving_mass_kg",
    "target_xpeak_m",
    "levels_m",
    "method",
    "order",
    "repeats",
    "priority",
    "preset",
    "part_spec",
    "limits",
    "recipe",
    "production",
];

fn number(v: &Value, field: &str, errors: &mut Vec<FieldError>) -> Option<f64> {
    match v.as_f64() {
        Some(x) if x.is_finite() => Some(x),
        _ => {
            errors.push(err(field, "must be a finite number"));
            None
        }
    }
}

fn text(v: &Value, field: &str, max: usize, errors: &mut Vec<FieldError>) -> Option<String> {
    match v.as_str() {
        Some(s) if s.len() <= max => Some(s.to_string()),
        Some(_) => {
            errors.push(err(field, format!("at most {max} characters")));
            None
        }
        None => {
            errors.push(err(field, "must be a string"));
            None
        }
    }
}

/// Resolves the part mounted on a virtual bench: `part_spec`, else `preset`,
/// else the bench's configured preset.
pub fn mounted_part(spec: &JobSpec, bench: &BenchConfig) -> Result<PartSpec, String> {
    if let Some(p) = &spec.part_spec {
        return Ok(p.clone());
    }
    if let Some(p) = &spec.production {
        return production_part(p);
    }
    let name = spec.preset.as_deref().unwrap_or(&bench.preset);
    crate::physics::preset(name)
}

/// The part a [`ProductionPart`] describes.
pub fn production_part(p: &ProductionPart) -> Result<PartSpec, String> {
    let nominal = crate::physics::preset(&p.preset)?;
    Ok(crate::physics::production::part(
        &nominal,
        &crate::physics::production::Spread::default(),
        p.seed,
        p.defect,
    ))
}

/// Validates a job body against the configuration; returns the accepted job.
pub fn validate(body: &Value, cfg: &Config) -> Result<JobSpec, Vec<FieldError>> {
    let mut errors = Vec::new();
    let Some(obj) = body.as_object() else {
        return Err(vec![err("", "the body must be a JSON object")]);
    };
    for k in obj.keys() {
        if !FIELDS.contains(&k.as_str()) {
            errors.push(err(k, "unknown field"));
        }
    }

    // part
    let mut part = None;
    match obj.get("part") {
        None => errors.push(err("part", "required: {\"serial\": \"...\"}")),
        Some(Value::Object(p)) => {
            for k in p.keys() {
                if !["serial", "kind", "notes"].contains(&k.as_str()) {
                    errors.push(err(&format!("part.{k}"), "unknown field"));
                }
            }
            let serial = match p.get("serial") {
                None => {
                    errors.push(err("part.serial", "required"));
                    None
                }
                Some(Value::String(s)) if valid_serial(s) => Some(s.clone()),
                Some(_) => {
                    errors.push(err("part.serial", SERIAL_RULE));
                    None
                }
            };
            let kind = p
                .get("kind")
                .filter(|v| !v.is_null())
                .and_then(|v| text(v, "part.kind", 64, &mut errors));
            let notes = p
                .get("notes")
                .filter(|v| !v.is_null())
                .and_then(|v| text(v, "part.notes", 4096, &mut errors));
            if let Some(serial) = serial {
                part = Some(PartRef {
                    serial,
                    kind,
                    notes,
                });
            }
        }
        Some(_) => errors.push(err("part", "must be an object with a serial")),
    }

    // bench
    let bench: Option<&BenchConfig> = match obj.get("bench") {
        None | Some(Value::Null) => cfg.benches.first(),
        Some(Value::String(id)) => {
            let b = cfg.benches.iter().find(|b| &b.id == id);
            if b.is_none() {
                let ids: Vec<_> = cfg.benches.iter().map(|b| b.id.as_str()).collect();
                errors.push(err(
                    "bench",
                    format!("unknown bench '{id}' (benches: {})", ids.join(", ")),
                ));
            }
            b
        }
        Some(_) => {
            errors.push(err("bench", "must be a bench id (string)"));
            None
        }
    };

    // limits: the bench's, or tighter
    let mut limits = bench.map(|b| b.limits);
    // null is absent, for every optional member (as the schema says).
    let given = |k: &str| obj.get(k).filter(|v| !v.is_null());
    if let (Some(v), Some(bl)) = (given("limits"), bench.map(|b| b.limits)) {
        match v.as_object() {
            Some(l) => {
                let mut out = bl;
                for k in l.keys() {
                    if !["max_displacement_m", "max_drive_v"].contains(&k.as_str()) {
                        errors.push(err(&format!("limits.{k}"), "unknown field"));
                    }
                }
                if let Some(x) = l.get("max_displacement_m") {
                    if let Some(x) = number(x, "limits.max_displacement_m", &mut errors) {
                        if x <= 0.0 || x > bl.max_displacement_m {
                            errors.push(err(
                                "limits.max_displacement_m",
                                format!(
                                    "must be in (0, {}] m (the bench's limit), got {x}",
                                    bl.max_displacement_m
                                ),
                            ));
                        } else {
                            out.max_displacement_m = x;
                        }
                    }
                }
                if let Some(x) = l.get("max_drive_v") {
                    if let Some(x) = number(x, "limits.max_drive_v", &mut errors) {
                        if x <= 0.0 || x > bl.max_drive_v {
                            errors.push(err(
                                "limits.max_drive_v",
                                format!(
                                    "must be in (0, {}] V (the bench's limit), got {x}",
                                    bl.max_drive_v
                                ),
                            ));
                        } else {
                            out.max_drive_v = x;
                        }
                    }
                }
                limits = Some(out);
            }
            None => errors.push(err("limits", "must be an object")),
        }
    }

    // levels
    let mut levels = Vec::new();
    match (given("target_xpeak_m"), given("levels_m")) {
        (Some(_), Some(_)) => errors.push(err(
            "levels_m",
            "give either target_xpeak_m or levels_m, not both",
        )),
        (Some(v), None) => {
            if let Some(x) = number(v, "target_xpeak_m", &mut errors) {
                levels.push(("target_xpeak_m".to_string(), x));
            }
        }
        (None, Some(Value::Array(a))) => {
            if a.is_empty() || a.len() > MAX_LEVELS {
                errors.push(err(
                    "levels_m",
                    format!("give 1 to {MAX_LEVELS} target peak displacements"),
                ));
            }
            for (i, v) in a.iter().enumerate() {
                let f = format!("levels_m[{i}]");
                if let Some(x) = number(v, &f, &mut errors) {
                    levels.push((f, x));
                }
            }
        }
        (None, Some(_)) => errors.push(err("levels_m", "must be a list of numbers (m)")),
        (None, None) => levels.push(("target_xpeak_m".to_string(), cfg.defaults.target_xpeak_m)),
    }
    for (f, x) in &levels {
        if *x <= 0.0 {
            errors.push(err(f, format!("must be > 0 m, got {x}")));
        } else if let Some(l) = limits {
            if *x > l.max_displacement_m {
                errors.push(err(
                    f,
                    format!(
                        "{x} m is beyond the displacement limit of {} m",
                        l.max_displacement_m
                    ),
                ));
            }
        }
    }

    let method = match obj.get("method") {
        None | Some(Value::Null) => cfg.defaults.method,
        Some(v) => match serde_json::from_value::<Method>(v.clone()) {
            Ok(m) => m,
            Err(_) => {
                errors.push(err("method", "must be \"two-signal\" or \"one-signal\""));
                cfg.defaults.method
            }
        },
    };
    let order = match obj.get("order") {
        None | Some(Value::Null) => cfg.defaults.order,
        Some(v) => match v.as_u64() {
            Some(n) if (1..=MAX_ORDER as u64).contains(&n) => Some(n as usize),
            _ => {
                errors.push(err(
                    "order",
                    format!("must be an integer from 1 to {MAX_ORDER}"),
                ));
                None
            }
        },
    };
    let repeats = match obj.get("repeats") {
        None | Some(Value::Null) => 1,
        Some(v) => match v.as_u64() {
            Some(n) if (1..=MAX_REPEATS as u64).contains(&n) => n as u32,
            _ => {
                errors.push(err(
                    "repeats",
                    format!("must be an integer from 1 to {MAX_REPEATS}"),
                ));
                1
            }
        },
    };
    let priority = match obj.get("priority") {
        None | Some(Value::Null) => 0,
        Some(v) => match v.as_i64() {
            Some(n) if (-1000..=1000).contains(&n) => n,
            _ => {
                errors.push(err("priority", "must be an integer from -1000 to 1000"));
                0
            }
        },
    };

    // the part mounted on the virtual bench
    let preset = match obj.get("preset") {
        None | Some(Value::Null) => None,
        Some(Value::String(name)) => {
            if crate::physics::preset(name).is_err() {
                errors.push(err(
                    "preset",
                    format!(
                        "unknown preset '{name}' (presets: {})",
                        crate::physics::preset_names().join(", ")
                    ),
                ));
            }
            Some(name.clone())
        }
        Some(_) => {
            errors.push(err("preset", "must be a preset name (string)"));
            None
        }
    };
    let part_spec = match obj.get("part_spec") {
        None | Some(Value::Null) => None,
        Some(v) => {
            if preset.is_some() {
                errors.push(err(
                    "part_spec",
                    "give either preset or part_spec, not both",
                ));
            }
            match serde_json::from_value::<PartSpec>(v.clone()) {
                Ok(p) => {
                    check_part_spec(&p, &mut errors);
                    Some(p)
                }
                Err(e) => {
                    errors.push(err("part_spec", e.to_string()));
                    None
                }
            }
        }
    };

    let production = match obj.get("production") {
        None | Some(Value::Null) => None,
        Some(v) => {
            if preset.is_some() || part_spec.is_some() {
                errors.push(err(
                    "production",
                    "give one of preset, part_spec and production",
                ));
            }
            match serde_json::from_value::<ProductionPart>(v.clone()) {
                Ok(p) => match production_part(&p) {
                    Ok(_) => Some(p),
                    Err(e) => {
                        errors.push(err("production.preset", e));
                        None
                    }
                },
                Err(e) => {
                    errors.push(err("production", e.to_string()));
                    None
                }
            }
        }
    };
    if let Some(v) = obj.get("recipe") {
        if !v.is_null() && !v.as_str().is_some_and(valid_serial) {
            errors.push(err("recipe", "must be a recipe name"));
        }
    }

    let moving_mass_kg = match obj.get("moving_mass_kg") {
        None | Some(Value::Null) => {
            // On the virtual bench it defaults to the mounted part's.
            let mounted = if let Some(p) = &part_spec {
                Ok(p.clone())
            } else if let Some(p) = &production {
                production_part(p)
            } else if let Some(name) = &preset {
                crate::physics::preset(name)
            } else if let Some(b) = bench {
                crate::physics::preset(&b.preset)
            } else {
                Err(String::new())
            };
            match mounted {
                Ok(p) => Some(p.moving_mass_kg),
                Err(e)
                    if preset.is_none()
                        && part_spec.is_none()
                        && production.is_none()
                        && bench.is_some() =>
                {
                    errors.push(err(
                        "moving_mass_kg",
                        format!("required: the mounted part's mass is not known ({e})"),
                    ));
                    None
                }
                Err(_) => None,
            }
        }
        Some(v) => match number(v, "moving_mass_kg", &mut errors) {
            Some(m) if (MIN_MOVING_MASS_KG..=10.0).contains(&m) => Some(m),
            Some(m) => {
                errors.push(err(
                    "moving_mass_kg",
                    format!("must be in [{MIN_MOVING_MASS_KG}, 10] kg, got {m}"),
                ));
                None
            }
            None => None,
        },
    };

    if !errors.is_empty() {
        return Err(errors);
    }
    match (part, bench, limits, moving_mass_kg) {
        (Some(part), Some(bench), Some(limits), Some(moving_mass_kg)) => Ok(JobSpec {
            part,
            bench: bench.id.clone(),
            moving_mass_kg,
            levels_m: levels.into_iter().map(|(_, x)| x).collect(),
            method,
            order,
            repeats,
            priority,
            preset,
            part_spec,
            limits,
            recipe: None,
            production,
            submitted_by: None,
        }),
        _ => Err(vec![err("", "invalid job")]),
    }
}

fn check_part_spec(p: &PartSpec, errors: &mut Vec<FieldError>) {
    if let Err(e) = p.validate() {
        errors.push(err("part_spec", e));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn fields(e: &[FieldError]) -> Vec<&str> {
        e.iter().map(|e| e.field.as_str()).collect()
    }

    #[test]
    fn minimal_job_takes_the_defaults() {
        let cfg = Config::default();
        let j = validate(
            &json!({"part": {"serial": "SN-1"}, "moving_mass_kg": 0.02}),
            &cfg,
        )
        .unwrap();
        assert_eq!(j.bench, "virtual-1");
        assert_eq!(j.levels_m, vec![cfg.defaults.target_xpeak_m]);
        assert_eq!(j.repeats, 1);
        assert_eq!(j.limits, cfg.benches[0].limits);
        assert_eq!(j.moving_mass_kg, 0.02);
        // The accepted job reads back unchanged.
        let back: JobSpec = serde_json::from_value(serde_json::to_value(&j).unwrap()).unwrap();
        assert_eq!(back, j);
    }

    #[test]
    fn every_bad_field_gets_its_own_message() {
        let cfg = Config::default();
        let e = validate(
            &json!({"part": {"serial": "a/b", "colour": 1}, "moving_mass_kg": -1.0,
                    "levels_m": [0.004, 0.5, "x"], "method": "three-signal", "order": 0,
                    "repeats": 100, "bench": "nope", "extra": true}),
            &cfg,
        )
        .unwrap_err();
        let f = fields(&e);
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
    }

    #[test]
    fn limits_may_only_be_tightened() {
        let cfg = Config::default();
        let base = json!({"part": {"serial": "S"}, "moving_mass_kg": 0.02});
        let mut b = base.clone();
        b["limits"] = json!({"max_displacement_m": 0.02});
        let e = validate(&b, &cfg).unwrap_err();
        assert_eq!(fields(&e), ["limits.max_displacement_m"]);
        b["limits"] = json!({"max_displacement_m": 0.005});
        b["target_xpeak_m"] = json!(0.006);
        let e = validate(&b, &cfg).unwrap_err();
        assert_eq!(fields(&e), ["target_xpeak_m"]);
        b["target_xpeak_m"] = json!(0.004);
        let j = validate(&b, &cfg).unwrap();
        assert_eq!(j.limits.max_displacement_m, 0.005);
        assert_eq!(j.limits.max_drive_v, cfg.benches[0].limits.max_drive_v);
    }

    #[test]
    fn non_finite_and_non_object_bodies_are_refused() {
        let cfg = Config::default();
        assert_eq!(fields(&validate(&json!([1]), &cfg).unwrap_err()), [""]);
        let e = validate(&json!({"moving_mass_kg": 0.02}), &cfg).unwrap_err();
        assert_eq!(fields(&e), ["part"]);
        let e = validate(
            &json!({"part": {"serial": "S"}, "moving_mass_kg": "heavy"}),
            &cfg,
        )
        .unwrap_err();
        assert_eq!(fields(&e), ["moving_mass_kg"]);
    }
}
