-- Imports honour Idempotency-Key (issue 11, decision 0021): the key, the
-- SHA-256 of the import's fields and the measurement it stored, written in
-- the same transaction as the measurement. A retry with the same key and the
-- same fields answers that measurement; with other fields, 409.
CREATE TABLE import_keys (
    idempotency_key  TEXT PRIMARY KEY,
    request_sha256   TEXT NOT NULL,
    measurement_id   TEXT NOT NULL REFERENCES measurements(id),
    created_at       TEXT NOT NULL
);
