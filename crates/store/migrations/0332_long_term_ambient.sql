-- Issue 32, decision 0130: the ambient conditions of each interval of a
-- long-term test (air temperature in K, relative humidity in %), each with
-- where it came from: the bench's configured sensor ('sensor', read at the
-- interval's start) or entered by hand ('hand', which replaces the
-- sensor's). NULL: not known (no sensor, a failed reading).
ALTER TABLE long_term_intervals ADD COLUMN temperature_k REAL;
ALTER TABLE long_term_intervals ADD COLUMN temperature_source TEXT
    CHECK (temperature_source IN ('sensor', 'hand'));
ALTER TABLE long_term_intervals ADD COLUMN relative_humidity_percent REAL;
ALTER TABLE long_term_intervals ADD COLUMN humidity_source TEXT
    CHECK (humidity_source IN ('sensor', 'hand'));
