-- One row rewritten by /readyz: a committed write proves the store can keep
-- results (a full disk or a read-only file makes it fail).
CREATE TABLE store_probe (
    id  INTEGER PRIMARY KEY CHECK (id = 1),
    at  TEXT NOT NULL
);
