-- Raw signals stored at their captured resolution (decision 0013): `wav` holds
-- FLAC (or WAV) bytes in the standard layout; `channel_scale_json` the physical
-- value of full scale per channel (NULL: a float32 WAV in physical units, as
-- rows before this migration). `pruned_at`: when the retention policy removed
-- the raw signals (the blob is then empty); results are never removed.
ALTER TABLE recordings ADD COLUMN channel_scale_json TEXT;
ALTER TABLE recordings ADD COLUMN pruned_at TEXT;
CREATE INDEX measurements_created ON measurements(created_at);
