-- Adaptive compensation: as migrations/0033_adaptation.sql (SQLite), in PostgreSQL's dialect
-- (the same).
ALTER TABLE trials ADD COLUMN adaptation_json TEXT;
