-- Fits of stored measurements (POST /api/v1/measurements/{id}/fits): every fit is kept.
CREATE TABLE fits (
    seq             INTEGER PRIMARY KEY AUTOINCREMENT,
    id              TEXT NOT NULL UNIQUE,
    measurement_id  TEXT NOT NULL REFERENCES measurements(id),
    request_json    TEXT NOT NULL,
    result_json     TEXT NOT NULL,
    software_version TEXT NOT NULL,
    created_at      TEXT NOT NULL
);
CREATE INDEX fits_measurement ON fits(measurement_id, seq);
