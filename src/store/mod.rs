//! SQLite storage (sqlx): parts, jobs, measurements, recordings, events.
