-- Issue 36 (decision 0105): the center is the only writer; a station
-- posts its items over HTTP(S) with its own token, bound to its id.

-- Every request or item the center refused, with why: a station claiming
-- another's id, a retired station, an item that contradicts itself or the
-- center's rules (a void of another station's measurement, a NUL byte).
-- One row per (claimed station, item, reason); a resend counts up.
CREATE TABLE ingest_refusals (
    seq               BIGSERIAL PRIMARY KEY,
    -- the station id the request claimed
    station_id        TEXT NOT NULL,
    -- the station its credential belongs to (NULL: no valid credential)
    credential_station TEXT,
    -- '' for a refused request (not an item)
    item_id           TEXT NOT NULL,
    item_seq          BIGINT,
    reason            TEXT NOT NULL,
    first_at          TEXT NOT NULL,
    last_at           TEXT NOT NULL,
    times             BIGINT NOT NULL DEFAULT 1,
    UNIQUE (station_id, item_id, reason)
);
CREATE INDEX ingest_refusals_station ON ingest_refusals (station_id, seq);

-- The station's clock against the center's at its last hello (s, station
-- minus center); renames and retirements made on purpose.
ALTER TABLE stations
    ADD COLUMN clock_skew_s DOUBLE PRECISION,
    ADD COLUMN retired_at TEXT,
    ADD COLUMN renamed_to TEXT;

-- A station's former names: its rows keep the name they were made under,
-- and the station owns them under its new name (void, correct).
CREATE TABLE station_names (
    former_id   TEXT PRIMARY KEY,
    station_id  TEXT NOT NULL,
    renamed_at  TEXT NOT NULL
);

-- Recordings are read in 1 MiB chunks for a download (substring()); FLAC
-- does not compress further, so store them uncompressed out of line and
-- a chunk reads only its own pages (rows stored from now on).
ALTER TABLE recordings ALTER COLUMN wav SET STORAGE EXTERNAL;
