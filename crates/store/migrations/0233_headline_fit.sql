-- Which fit supplies a measurement's headline figures (issue 23), chosen by a
-- person: every choice is kept (who and when); the newest one holds. A row
-- with fit_id NULL goes back to the measurement's own (base) result.
CREATE TABLE headline_choices (
    seq             INTEGER PRIMARY KEY AUTOINCREMENT,
    measurement_id  TEXT NOT NULL REFERENCES measurements(id),
    fit_id          TEXT REFERENCES fits(id),
    chosen_by       TEXT,
    chosen_at       TEXT NOT NULL
);
CREATE INDEX headline_choices_measurement ON headline_choices(measurement_id, seq);
