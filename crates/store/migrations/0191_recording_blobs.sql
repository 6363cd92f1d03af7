-- Bytes of recordings written in chunks (store/blob.rs, decision 0021a): large
-- imports. The blob is the row's only stored field, so SQLite keeps the
-- zeroblob(N) it is created with unexpanded while sqlite3_blob_write fills it
-- (in `recordings.wav`, followed by other columns, SQLite would allocate N
-- bytes of zeros and a record of N bytes). Such a recording has `wav` = X''.
CREATE TABLE recording_blobs (
    recording_id  INTEGER PRIMARY KEY REFERENCES recordings(id),
    bytes         BLOB NOT NULL
);
