-- Where a recipe version was authored (issue 36, decision 0106): `center`
-- (the fleet's center sent it; approved_by is its approver there) or
-- `local` (made on this station only). Versions stored before are local
-- until the next recipe sync finds the same version at the center.
ALTER TABLE qc_recipes ADD COLUMN source TEXT NOT NULL DEFAULT 'local';
ALTER TABLE qc_recipes ADD COLUMN approved_by TEXT;
