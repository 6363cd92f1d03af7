//! The job request in the daemon: the typed request, its checks and the
//! accepted [`JobSpec`] live in the core (`springbench_core::job`); here the
//! station's configuration becomes the [`Admission`] they are checked
//! against, and the runner finds the part mounted on a virtual bench.

use crate::config::{BenchConfig, Config};
use crate::physics::PartSpec;

pub use crate::job::{
    production_part, valid_serial, Admission, BenchOffer, FieldError, JobLimits, JobPart,
    JobProduction, JobRequest, JobSpec, Limits, RecipeRef, MAX_LEVELS, MAX_ORDER, MAX_REPEATS,
    MIN_MOVING_MASS_KG, SERIAL_RULE,
};

/// What a job request is checked against on this station: its benches (the
/// first is the default) and the configured defaults.
pub fn admission(cfg: &Config) -> Admission {
    Admission {
        benches: cfg
            .benches
            .iter()
            .map(|b| BenchOffer {
                id: b.id.clone(),
                limits: b.limits,
                preset: b.preset.clone(),
            })
            .collect(),
        target_xpeak_m: cfg.defaults.target_xpeak_m,
        method: cfg.defaults.method,
        order: cfg.defaults.order,
    }
}

/// Checks a job body against the configuration (no recipe); returns the
/// accepted job or one message per bad field.
pub fn validate(body: &serde_json::Value, cfg: &Config) -> Result<JobSpec, Vec<FieldError>> {
    JobRequest::check(crate::job::parse_lenient(body), &admission(cfg), |_| Ok(()))
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
