-- Diagnostics and plots derived from a fit, computed once and kept (fits are
-- immutable, so nothing is ever invalidated). fit_id '' is the measurement's
-- own fit (its stored result). name: 'diagnostics.json' or '<plot>.svg'.
-- status: the HTTP status of the answer (200, or a problem's status when the
-- computation failed for this fit's data: it would fail again).
CREATE TABLE derived (
    measurement_id    TEXT NOT NULL REFERENCES measurements(id),
    fit_id            TEXT NOT NULL DEFAULT '',
    name              TEXT NOT NULL,
    status            INTEGER NOT NULL,
    content_type      TEXT NOT NULL,
    body              BLOB NOT NULL,
    software_version  TEXT NOT NULL,
    created_at        TEXT NOT NULL,
    PRIMARY KEY (measurement_id, fit_id, name)
);
