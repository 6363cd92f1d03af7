//! What the read handlers of the UI's parts, measurement, compare and QC
//! views need of a daemon: its results store. A station answers from its
//! SQLite ([`super::AppState`]), the fleet's center from PostgreSQL
//! ([`super::fleet::FleetState`]); the same handlers serve both, so a
//! route answers the same shape at a station and at the center (there with
//! the station of every row; issue 20, decision 0034).

use crate::store::corrections::Corrections;
use crate::store::ResultStore;

/// A daemon's state whose results the read handlers read.
pub trait Reads: Clone + Send + Sync + 'static {
    /// The backend: the station's `Store` or the center's `PgStore`.
    type Store: ResultStore + Corrections + Send + Sync + 'static;
    fn results(&self) -> &Self::Store;
    /// The most verdicts `GET /api/v1/recipes/{name}/spc` reads for one
    /// answer (it reads each verdict of the window to give the chart's points).
    const SPC_WINDOW_MAX: i64 = 100_000;
    /// Appended to the 422 of a larger window.
    const SPC_WINDOW_HINT: &'static str = "";
}

impl Reads for super::AppState {
    type Store = crate::store::Store;
    fn results(&self) -> &Self::Store {
        &self.store
    }
}
