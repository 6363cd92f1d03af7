//! The memory's studies (issue 33, decision 0121): a study job's own state
//! (`awaiting_operator` while the operator adds the mass; the job stays
//! `running`), the instruction, the confirmation and the typed result.

use crate::{now, Store, StoreResult};
use springbench_core::diagnose::studies::{StudyResult, StudyState};
use sqlx::Row;

/// A study's row.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct StudyRow {
    pub job_id: String,
    /// `added_mass` or `recovery`.
    pub kind: String,
    pub state: StudyState,
    /// What the operator must do while `awaiting_operator`.
    pub instruction: Option<String>,
    pub result: Option<StudyResult>,
    pub confirmed_by: Option<String>,
    pub updated_at: String,
}

impl Store {
    /// Sets a study's state and instruction (the row is made on its first state).
    pub async fn set_study_state(
        &self,
        job_id: &str,
        kind: &str,
        state: StudyState,
        instruction: Option<&str>,
    ) -> StoreResult<()> {
        sqlx::query(
            "INSERT INTO studies (job_id, kind, state, instruction, updated_at) VALUES (?, ?, ?, ?, ?) \
             ON CONFLICT(job_id) DO UPDATE SET state = excluded.state, instruction = excluded.instruction, updated_at = excluded.updated_at",
        )
        .bind(job_id.to_string())
        .bind(kind.to_string())
        .bind(state.as_str())
        .bind(instruction.map(str::to_string))
        .bind(now())
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(())
    }

    /// `awaiting_operator` -> `confirmed`; false when the study does not wait.
    pub async fn confirm_study(&self, job_id: &str, by: Option<&str>) -> StoreResult<bool> {
        let r = sqlx::query(
            "UPDATE studies SET state = 'confirmed', confirmed_by = ?, updated_at = ? WHERE job_id = ? AND state = 'awaiting_operator'",
        )
        .bind(by.map(str::to_string))
        .bind(now())
        .bind(job_id.to_string())
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(r.rows_affected() == 1)
    }

    /// The study's end: its result (succeeded) or none (failed).
    pub async fn finish_study(
        &self,
        job_id: &str,
        kind: &str,
        result: Option<&StudyResult>,
    ) -> StoreResult<()> {
        let state = if result.is_some() {
            StudyState::Succeeded
        } else {
            StudyState::Failed
        };
        let text = result
            .map(serde_json::to_string)
            .transpose()
            .map_err(|e| crate::StoreError::Corrupt(format!("study result: {e}")))?;
        sqlx::query(
            "INSERT INTO studies (job_id, kind, state, result_json, updated_at) VALUES (?, ?, ?, ?, ?) \
             ON CONFLICT(job_id) DO UPDATE SET state = excluded.state, instruction = NULL, result_json = excluded.result_json, updated_at = excluded.updated_at",
        )
        .bind(job_id.to_string())
        .bind(kind.to_string())
        .bind(state.as_str())
        .bind(text)
        .bind(now())
        .execute(&mut *self.writer().await?)
        .await?;
        Ok(())
    }

    pub async fn get_study(&self, job_id: &str) -> StoreResult<Option<StudyRow>> {
        let Some(r) = sqlx::query(
            "SELECT job_id, kind, state, instruction, result_json, confirmed_by, updated_at FROM studies WHERE job_id = ?",
        )
        .bind(job_id.to_string())
        .fetch_optional(&self.pool)
        .await?
        else {
            return Ok(None);
        };
        let state: String = r.get("state");
        let result: Option<String> = r.get("result_json");
        Ok(Some(StudyRow {
            job_id: r.get("job_id"),
            kind: r.get("kind"),
            state: StudyState::parse(&state)
                .ok_or_else(|| crate::StoreError::Corrupt(format!("study state '{state}'")))?,
            instruction: r.get("instruction"),
            result: result
                .map(|t| serde_json::from_str(&t))
                .transpose()
                .map_err(|e| crate::StoreError::Corrupt(format!("study result: {e}")))?,
            confirmed_by: r.get("confirmed_by"),
            updated_at: r.get("updated_at"),
        }))
    }
}
