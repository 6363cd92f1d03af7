-- Recipes authored at the center (issue 36, decision 0106). An author
-- proposes a recipe (a new one, a new version, new limits); an approver
-- (not the same person) approves it into a version of qc_recipes, which
-- the stations take, or rejects it. A station may propose its local
-- recipe (station_id set). Nothing is deleted: decided proposals stay.
CREATE TABLE recipe_proposals (
    seq           BIGSERIAL PRIMARY KEY,
    id            TEXT NOT NULL UNIQUE,
    recipe_name   TEXT NOT NULL,
    -- create | limits | edit (against base_version)
    kind          TEXT NOT NULL,
    -- The newest version when proposed (None: a new recipe).
    base_version  BIGINT,
    sha256        TEXT NOT NULL,
    body_json     JSONB NOT NULL,
    note          TEXT,
    -- proposed | approved | rejected
    state         TEXT NOT NULL DEFAULT 'proposed',
    proposed_by   TEXT,
    -- A station publishing its local recipe (its version there).
    station_id    TEXT,
    station_version BIGINT,
    proposed_at   TEXT NOT NULL,
    decided_by    TEXT,
    decided_at    TEXT,
    reason        TEXT,
    approved_version BIGINT
);
CREATE INDEX recipe_proposals_recipe ON recipe_proposals (recipe_name, seq);

-- Who approved a center version (from its proposal).
ALTER TABLE qc_recipes ADD COLUMN approved_by TEXT;
