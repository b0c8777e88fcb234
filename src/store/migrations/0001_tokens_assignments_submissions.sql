-- One schema for SQLite and PostgreSQL: only types both read the same way (TEXT,
-- BIGINT, DOUBLE PRECISION), times as milliseconds since the Unix epoch, JSON as TEXT.

-- Bearer tokens. Only the SHA-256 of a token is kept (lowercase hex); the token itself
-- is shown once, when it is created.
CREATE TABLE tokens (
    id            TEXT PRIMARY KEY,
    role          TEXT NOT NULL CHECK (role IN ('instructor', 'grader')),
    -- The assignment a grader token is scoped to; NULL: every assignment.
    assignment_id TEXT,
    hash          TEXT NOT NULL UNIQUE,
    created_ms    BIGINT NOT NULL,
    revoked_ms    BIGINT
);

-- Every revision of every assignment document; the latest revision not deleted is the
-- assignment. Submissions name the revision they were graded against.
CREATE TABLE assignments (
    id          TEXT NOT NULL,
    revision    BIGINT NOT NULL,
    document    TEXT NOT NULL,
    created_ms  BIGINT NOT NULL,
    deleted_ms  BIGINT,
    PRIMARY KEY (id, revision)
);

-- One row per graded submission. A retried submission with the same idempotency key
-- finds its row instead of adding a second one (NULL keys never collide).
CREATE TABLE submissions (
    id              TEXT PRIMARY KEY,
    assignment_id   TEXT NOT NULL,
    revision        BIGINT NOT NULL,
    student         TEXT NOT NULL,
    idempotency_key TEXT,
    submitted_ms    BIGINT NOT NULL,
    result          TEXT NOT NULL,
    score           DOUBLE PRECISION NOT NULL,
    UNIQUE (assignment_id, idempotency_key)
);

CREATE INDEX submissions_by_student ON submissions (assignment_id, student, submitted_ms);
