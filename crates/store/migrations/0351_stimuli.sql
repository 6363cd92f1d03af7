-- Stimulus files uploaded to the station (issue 32, decision 0144): a
-- long-term test's WAV stimulus names one by its id, the SHA-256 of its
-- bytes (the same file uploaded twice is one row). The file is kept as it
-- was sent, with what the daemon read from it.
CREATE TABLE stimuli (
    id             TEXT PRIMARY KEY CHECK (length(id) = 64),
    created_at     TEXT NOT NULL,
    uploaded_by    TEXT,
    file_name      TEXT,
    sample_rate_hz INTEGER NOT NULL CHECK (sample_rate_hz > 0),
    frames         INTEGER NOT NULL CHECK (frames > 0),
    bits           INTEGER NOT NULL,
    sample_format  TEXT NOT NULL CHECK (sample_format IN ('int', 'float')),
    rms_fs         REAL NOT NULL CHECK (rms_fs > 0),
    peak_fs        REAL NOT NULL CHECK (peak_fs > 0),
    bytes          BLOB NOT NULL
);
