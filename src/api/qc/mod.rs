//! Production QC over HTTP: recipes (versioned), golden-unit limit
//! proposals and their approval, verdicts, SPC; and the MES outbox.
//! Translation only: the statistics are `crate::qc`, the tables `store::qc`.
//!
//! - `recipes.rs`: recipes, their versions and retirement, the recipe a job names;
//! - `limits.rs`: limit proposals from golden units, approval, rejection;
//! - `verdicts.rs`: a part's and a job's verdict, SPC of a recipe;
//! - `lot.rs`: the lot export (CSV, the table is `crate::qc::lot`);
//! - `outbox.rs`: the MES outbox (list, retry, drop).

mod limits;
mod lot;
mod outbox;
mod recipes;
mod verdicts;

pub use limits::*;
pub use lot::*;
pub use outbox::*;
pub use recipes::*;
pub use verdicts::*;

use super::problem::{ApiResult, Problem};
use serde_json::Value;

/// Parses a JSON body into `T`; a failure is a 422 naming the field it
/// failed at (`procedure.levels_m[2]`; `body` for the document itself).
pub fn parse_body<T: serde::de::DeserializeOwned>(body: Value) -> ApiResult<T> {
    serde_path_to_error::deserialize(body).map_err(|e| {
        let path = e.path().to_string();
        let field = if path.is_empty() || path == "." {
            "body".to_string()
        } else {
            path
        };
        Problem::field(&field, e.into_inner().to_string())
    })
}
