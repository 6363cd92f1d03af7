-- Issue 12: a job carries the warnings of its execution (e.g. a target level
-- not reached within the limits: target and reached Xpeak), beside its log.
ALTER TABLE jobs ADD COLUMN warnings_json TEXT;
