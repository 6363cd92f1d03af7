//! Recipes authored at the center (issue 36, decision 0106): an author
//! proposes a recipe (a new one, a new version, new limits), an approver
//! who is not its author approves it into a version of `qc_recipes` (which
//! the stations take, `CenterIngest::recipes`) or rejects it. A station may
//! propose its local recipe. Typed in and out: the recipe is a
//! [`Recipe`], stored as jsonb and read back whole.

use crate::reads::{recipe_cols, recipe_from_row};
use crate::PgStore;
use serde::{Deserialize, Serialize};
use springbench_core::qc::Recipe;
use springbench_store::results::RecipeRow;
use springbench_store::{now, StoreError, StoreResult};
use sqlx::postgres::PgRow;
use sqlx::Row;

/// Where a proposal stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ProposalState {
    Proposed,
    Approved,
    Rejected,
}

impl ProposalState {
    fn as_str(self) -> &'static str {
        match self {
            ProposalState::Proposed => "proposed",
            ProposalState::Approved => "approved",
            ProposalState::Rejected => "rejected",
        }
    }
}

/// What a proposal changes, against the version it was made on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ProposalKind {
    /// A recipe the center does not hold yet (version 1).
    Create,
    /// Limits only (the parameters' bounds, the K(x) mask).
    Limits,
    /// Anything else (procedure, parameters, validity...).
    Edit,
}

/// A recipe proposal at the center.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RecipeProposal {
    pub id: String,
    pub recipe_name: String,
    pub kind: ProposalKind,
    /// The newest version when proposed (null: a new recipe). Approval
    /// needs the recipe still at this version.
    pub base_version: Option<i64>,
    /// The proposed recipe's content hash.
    pub sha256: String,
    #[schema(value_type = springbench_core::qc::Recipe)]
    pub recipe: Recipe,
    pub note: Option<String>,
    pub state: ProposalState,
    /// The author's token name (`station:<id>` for a station's publication).
    pub proposed_by: Option<String>,
    /// A station publishing its local recipe, and the version it holds.
    pub station_id: Option<String>,
    pub station_version: Option<i64>,
    pub proposed_at: String,
    pub decided_by: Option<String>,
    pub decided_at: Option<String>,
    /// Why it was rejected.
    pub reason: Option<String>,
    /// The recipe version it became.
    pub approved_version: Option<i64>,
}

/// A proposal to store.
#[derive(Debug, Clone)]
pub struct NewRecipeProposal {
    pub id: String,
    pub recipe: Recipe,
    /// The version the author saw (None: the newest, or a new recipe).
    pub base_version: Option<i64>,
    pub note: Option<String>,
    pub proposed_by: Option<String>,
    pub station_id: Option<String>,
    pub station_version: Option<i64>,
}

/// What [`PgStore::propose_recipe`] did.
#[derive(Debug, Clone)]
pub enum Proposed {
    Stored(Box<RecipeProposal>),
    /// The recipe is not at `base_version` (its newest version, if any).
    Stale(Option<i64>),
    /// The same content as the newest live version: nothing to approve.
    Unchanged(i64),
}

/// What [`PgStore::decide_recipe_proposal`] did.
#[derive(Debug, Clone)]
pub enum Decided {
    /// Approved: the new version the stations take.
    Approved(Box<RecipeRow>),
    Rejected(Box<RecipeProposal>),
    /// No such proposal.
    Unknown,
    /// Approved or rejected before.
    AlreadyDecided(Box<RecipeProposal>),
    /// The recipe moved on since the proposal (why).
    Stale(String),
}

/// The recipe without its limits: two recipes equal under it differ in
/// limits only.
fn without_limits(r: &Recipe) -> Recipe {
    let mut r = r.clone();
    r.kx_mask = None;
    for p in &mut r.parameters {
        p.lower = None;
        p.upper = None;
        p.from_golden = None;
    }
    r
}

macro_rules! proposal_cols {
    () => {
        "id, recipe_name, base_version, sha256, body_json::text AS body_json, note, state, proposed_by, \
         station_id, station_version, proposed_at, decided_by, decided_at, reason, approved_version, kind"
    };
}

fn proposal_from_row(r: &PgRow) -> StoreResult<RecipeProposal> {
    let id: String = r.get("id");
    let recipe: Recipe = serde_json::from_str(&r.get::<String, _>("body_json"))
        .map_err(|e| StoreError::Corrupt(format!("recipe proposal {id} unreadable: {e}")))?;
    let state = match r.get::<String, _>("state").as_str() {
        "proposed" => ProposalState::Proposed,
        "approved" => ProposalState::Approved,
        "rejected" => ProposalState::Rejected,
        s => {
            return Err(StoreError::Corrupt(format!(
                "recipe proposal {id}: state '{s}'"
            )))
        }
    };
    let kind = match r.get::<String, _>("kind").as_str() {
        "create" => ProposalKind::Create,
        "limits" => ProposalKind::Limits,
        _ => ProposalKind::Edit,
    };
    Ok(RecipeProposal {
        recipe_name: r.get("recipe_name"),
        kind,
        base_version: r.get("base_version"),
        sha256: r.get("sha256"),
        recipe,
        note: r.get("note"),
        state,
        proposed_by: r.get("proposed_by"),
        station_id: r.get("station_id"),
        station_version: r.get("station_version"),
        proposed_at: r.get("proposed_at"),
        decided_by: r.get("decided_by"),
        decided_at: r.get("decided_at"),
        reason: r.get("reason"),
        approved_version: r.get("approved_version"),
        id,
    })
}

impl PgStore {
    /// Stores a proposal made on the recipe's newest version (or on
    /// `base_version` when the author names it: then the recipe must still
    /// be there).
    pub async fn propose_recipe(&self, p: &NewRecipeProposal) -> StoreResult<Proposed> {
        let name = &p.recipe.name;
        let mut tx = self.pool.begin().await?;
        sqlx::query("SELECT pg_advisory_xact_lock(hashtext('qc_recipes:' || $1))")
            .bind(name)
            .execute(&mut *tx)
            .await?;
        let cur = sqlx::query(concat!(
            "SELECT ",
            recipe_cols!(),
            " FROM qc_recipes WHERE name = $1 ORDER BY version DESC LIMIT 1"
        ))
        .bind(name)
        .fetch_optional(&mut *tx)
        .await?
        .map(|r| recipe_from_row(&r))
        .transpose()?;
        let cur_version = cur.as_ref().map(|c| c.version);
        if p.base_version.is_some() && p.base_version != cur_version {
            return Ok(Proposed::Stale(cur_version));
        }
        let sha = p.recipe.sha256();
        let kind = match &cur {
            None => ProposalKind::Create,
            Some(c) if c.sha256 == sha && !c.retired => return Ok(Proposed::Unchanged(c.version)),
            Some(c) if without_limits(&c.recipe) == without_limits(&p.recipe) => {
                ProposalKind::Limits
            }
            Some(_) => ProposalKind::Edit,
        };
        let body = serde_json::to_string(&p.recipe)
            .map_err(|e| StoreError::Invalid(format!("recipe: {e}")))?;
        let row = sqlx::query(concat!(
            "INSERT INTO recipe_proposals (id, recipe_name, base_version, sha256, body_json, note, \
             proposed_by, station_id, station_version, proposed_at, kind) \
             VALUES ($1, $2, $3, $4, $5::jsonb, $6, $7, $8, $9, $10, $11) RETURNING ",
            proposal_cols!()
        ))
        .bind(&p.id)
        .bind(name)
        .bind(cur_version)
        .bind(&sha)
        .bind(body)
        .bind(&p.note)
        .bind(&p.proposed_by)
        .bind(&p.station_id)
        .bind(p.station_version)
        .bind(now())
        .bind(match kind {
            ProposalKind::Create => "create",
            ProposalKind::Limits => "limits",
            ProposalKind::Edit => "edit",
        })
        .fetch_one(&mut *tx)
        .await?;
        let stored = proposal_from_row(&row)?;
        tx.commit().await?;
        Ok(Proposed::Stored(Box::new(stored)))
    }

    /// A proposal by id.
    pub async fn recipe_proposal(&self, id: &str) -> StoreResult<Option<RecipeProposal>> {
        sqlx::query(concat!(
            "SELECT ",
            proposal_cols!(),
            " FROM recipe_proposals WHERE id = $1"
        ))
        .bind(id)
        .fetch_optional(&self.pool)
        .await?
        .map(|r| proposal_from_row(&r))
        .transpose()
    }

    /// Proposals, newest first (of one recipe, in one state), a keyset page
    /// before `before_seq`: (seq, proposal).
    pub async fn recipe_proposals(
        &self,
        recipe: Option<&str>,
        state: Option<ProposalState>,
        before_seq: Option<i64>,
        limit: i64,
    ) -> StoreResult<Vec<(i64, RecipeProposal)>> {
        let rows = sqlx::query(concat!(
            "SELECT seq, ",
            proposal_cols!(),
            " FROM recipe_proposals WHERE ($1::text IS NULL OR recipe_name = $1) \
             AND ($2::text IS NULL OR state = $2) AND ($3::bigint IS NULL OR seq < $3) \
             ORDER BY seq DESC LIMIT $4"
        ))
        .bind(recipe)
        .bind(state.map(ProposalState::as_str))
        .bind(before_seq)
        .bind(limit)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| Ok((r.get::<i64, _>("seq"), proposal_from_row(r)?)))
            .collect()
    }

    /// Approves (`approve`) or rejects a proposal, by `by`, in one
    /// transaction: an approval writes the next version of the recipe
    /// (origin `created`, `edited` or `limits_approved`; its proposal, its
    /// author as `created_by` and its approver), only while the recipe is
    /// still at the version the proposal was made on.
    pub async fn decide_recipe_proposal(
        &self,
        id: &str,
        approve: bool,
        by: Option<&str>,
        reason: Option<&str>,
    ) -> StoreResult<Decided> {
        let mut tx = self.pool.begin().await?;
        let Some(p) = sqlx::query(concat!(
            "SELECT ",
            proposal_cols!(),
            " FROM recipe_proposals WHERE id = $1 FOR UPDATE"
        ))
        .bind(id)
        .fetch_optional(&mut *tx)
        .await?
        .map(|r| proposal_from_row(&r))
        .transpose()?
        else {
            return Ok(Decided::Unknown);
        };
        if p.state != ProposalState::Proposed {
            return Ok(Decided::AlreadyDecided(Box::new(p)));
        }
        let t = now();
        if !approve {
            let row = sqlx::query(concat!(
                "UPDATE recipe_proposals SET state = 'rejected', decided_by = $2, decided_at = $3, reason = $4 \
                 WHERE id = $1 RETURNING ",
                proposal_cols!()
            ))
            .bind(id)
            .bind(by)
            .bind(&t)
            .bind(reason)
            .fetch_one(&mut *tx)
            .await?;
            let p = proposal_from_row(&row)?;
            tx.commit().await?;
            return Ok(Decided::Rejected(Box::new(p)));
        }
        let name = &p.recipe_name;
        sqlx::query("SELECT pg_advisory_xact_lock(hashtext('qc_recipes:' || $1))")
            .bind(name)
            .execute(&mut *tx)
            .await?;
        let cur: Option<i64> =
            sqlx::query_scalar("SELECT MAX(version) FROM qc_recipes WHERE name = $1")
                .bind(name)
                .fetch_one(&mut *tx)
                .await?;
        if cur != p.base_version {
            return Ok(Decided::Stale(match (p.base_version, cur) {
                (Some(b), Some(c)) => format!(
                    "the proposal was made on version {b} of recipe '{name}', which is at version {c} now; \
                     approving it would undo the changes since: propose again from the current version"
                ),
                (None, Some(c)) => format!(
                    "the proposal creates recipe '{name}', which exists now (version {c}): propose a new version"
                ),
                (_, None) => format!("recipe '{name}' is not stored"),
            }));
        }
        let origin = match p.kind {
            ProposalKind::Create => "created",
            ProposalKind::Limits => "limits_approved",
            ProposalKind::Edit => "edited",
        };
        let body = serde_json::to_string(&p.recipe)
            .map_err(|e| StoreError::Invalid(format!("recipe: {e}")))?;
        let row = sqlx::query(concat!(
            "INSERT INTO qc_recipes (name, version, sha256, body_json, origin, proposal_id, created_by, created_at, approved_by) \
             VALUES ($1, $2, $3, $4::jsonb, $5, $6, $7, $8, $9) RETURNING ",
            recipe_cols!()
        ))
        .bind(name)
        .bind(cur.map_or(1, |c| c + 1))
        .bind(&p.sha256)
        .bind(body)
        .bind(origin)
        .bind(id)
        .bind(&p.proposed_by)
        .bind(&t)
        .bind(by)
        .fetch_one(&mut *tx)
        .await?;
        let version = recipe_from_row(&row)?;
        sqlx::query(
            "UPDATE recipe_proposals SET state = 'approved', decided_by = $2, decided_at = $3, approved_version = $4 \
             WHERE id = $1",
        )
        .bind(id)
        .bind(by)
        .bind(&t)
        .bind(version.version)
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(Decided::Approved(Box::new(version)))
    }
}
