//! A recipe's procedure settings filled into a job request, once, typed.

use super::ProcedureSettings;
use crate::job::{FieldError, JobRequest};
use serde::Serialize;

/// Fills `value` into an absent `slot`; a given value must equal it.
fn fill<T: PartialEq + Clone + Serialize>(
    slot: &mut Option<T>,
    value: &T,
    field: &str,
    recipe: &str,
    errors: &mut Vec<FieldError>,
) {
    match slot {
        None => *slot = Some(value.clone()),
        Some(given) if given == value => {}
        Some(_) => {
            let v = serde_json::to_string(value).unwrap_or_default();
            errors.push(FieldError::new(
                field,
                format!("recipe '{recipe}' sets {field} = {v}; leave it out"),
            ));
        }
    }
}

impl ProcedureSettings {
    /// Fills these settings (of the recipe named `recipe`) into `req`: the
    /// levels, method and repeats, and the order and moving mass when the
    /// recipe sets them. A member the request gives must agree.
    pub fn apply_to(&self, recipe: &str, req: &mut JobRequest) -> Result<(), Vec<FieldError>> {
        let mut errors = vec![];
        if req.target_xpeak_m.is_some() {
            errors.push(FieldError::new(
                "target_xpeak_m",
                format!("recipe '{recipe}' sets the levels"),
            ));
        }
        fill(
            &mut req.levels_m,
            &self.levels_m,
            "levels_m",
            recipe,
            &mut errors,
        );
        fill(&mut req.method, &self.method, "method", recipe, &mut errors);
        fill(
            &mut req.repeats,
            &self.repeats,
            "repeats",
            recipe,
            &mut errors,
        );
        if let Some(o) = &self.order {
            fill(&mut req.order, o, "order", recipe, &mut errors);
        }
        // The procedure is the recipe's unless the job names one (a gauge
        // study runs both procedures on the same parts under one recipe).
        if req.procedure.is_none() {
            req.procedure = Some(self.mode);
        }
        if let Some(m) = &self.moving_mass_kg {
            fill(
                &mut req.moving_mass_kg,
                m,
                "moving_mass_kg",
                recipe,
                &mut errors,
            );
        }
        if errors.is_empty() {
            Ok(())
        } else {
            Err(errors)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::Method;
    use crate::job::JobPart;

    fn settings() -> ProcedureSettings {
        ProcedureSettings {
            levels_m: vec![0.002, 0.004],
            method: Method::TwoSignal,
            order: Some(6),
            repeats: 2,
            moving_mass_kg: None,
            mode: Default::default(),
            golden: None,
        }
    }

    fn request() -> JobRequest {
        JobRequest {
            part: JobPart {
                serial: "S".into(),
                ..JobPart::default()
            },
            ..JobRequest::default()
        }
    }

    #[test]
    fn fills_what_the_request_leaves_out() {
        let mut r = request();
        r.moving_mass_kg = Some(0.02);
        settings().apply_to("r", &mut r).unwrap();
        assert_eq!(r.levels_m, Some(vec![0.002, 0.004]));
        assert_eq!(r.method, Some(Method::TwoSignal));
        assert_eq!((r.order, r.repeats), (Some(6), Some(2)));
        // the recipe sets no mass: the request's stays
        assert_eq!(r.moving_mass_kg, Some(0.02));
        // the recipe's procedure unless the job names one (a gauge study runs both)
        assert_eq!(r.procedure, Some(crate::job::ProcedureMode::Full));
        let mut p = request();
        p.procedure = Some(crate::job::ProcedureMode::Production);
        let mut s = settings();
        s.mode = crate::job::ProcedureMode::Full;
        s.apply_to("r", &mut p).unwrap();
        assert_eq!(p.procedure, Some(crate::job::ProcedureMode::Production));
        // a request that agrees is accepted as is
        let before = r.clone();
        settings().apply_to("r", &mut r).unwrap();
        assert_eq!(r, before);
    }

    #[test]
    fn a_conflicting_member_is_named() {
        let mut r = request();
        r.target_xpeak_m = Some(0.004);
        r.repeats = Some(3);
        r.method = Some(Method::OneSignal);
        let e = settings().apply_to("r1", &mut r).unwrap_err();
        let f: Vec<&str> = e.iter().map(|e| e.field.as_str()).collect();
        assert_eq!(f, ["target_xpeak_m", "method", "repeats"]);
        assert_eq!(e[2].message, "recipe 'r1' sets repeats = 2; leave it out");
    }
}
