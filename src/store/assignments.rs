//! Assignment documents, kept by revision, and the submissions graded against them.
//! Documents and results are stored as the JSON text they were validated or produced
//! as; this module neither parses nor grades them.

use sqlx::Row;

use super::{Store, StoreError, now_ms, random_bytes};

/// The stored revision of an assignment.
#[derive(Debug, Clone, PartialEq)]
pub struct StoredAssignment {
    /// 1 for the first document, one more for each replacement.
    pub revision: i64,
    /// The document (JSON).
    pub document: String,
}

/// What putting an assignment did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Put {
    /// The revision the document was stored as.
    pub revision: i64,
    /// Whether there was no live assignment with this id before (created, not replaced).
    pub created: bool,
}

/// A live assignment as listed: its id and its latest revision.
#[derive(Debug, Clone, PartialEq)]
pub struct ListedAssignment {
    /// The id.
    pub id: String,
    /// The latest revision and its document.
    pub stored: StoredAssignment,
}

/// Why an assignment could not be put.
#[derive(Debug, thiserror::Error)]
pub enum PutError {
    /// The caller expected another revision than the stored one (409).
    #[error("the assignment is at revision {current}, not {expected}")]
    Conflict {
        /// What the caller said it replaces.
        expected: i64,
        /// What is stored (0: nothing).
        current: i64,
    },
    /// The database failed.
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// A submission to record.
#[derive(Debug, Clone)]
pub struct NewSubmission<'a> {
    /// The assignment.
    pub assignment: &'a str,
    /// The revision it was graded against.
    pub revision: i64,
    /// The student's opaque id.
    pub student: &'a str,
    /// The client's `Idempotency-Key`, if it sent one.
    pub idempotency_key: Option<&'a str>,
    /// The graded result (JSON).
    pub result: &'a str,
    /// The score.
    pub score: f64,
}

/// A limit on one student's submissions to one assignment: at most `limit` recorded
/// after `since_ms`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// Submissions allowed in the window.
    pub limit: u32,
    /// Where the window starts (ms since the epoch).
    pub since_ms: i64,
}

/// What recording a submission within a [`Window`] did.
#[derive(Debug, Clone, PartialEq)]
pub enum Recorded {
    /// Recorded now.
    New(Submission),
    /// Recorded before under the same idempotency key: that one.
    Existing(Submission),
    /// Not recorded: the window holds `limit` submissions already.
    Limited {
        /// When the oldest of the newest `limit` was recorded: the window frees a place
        /// when it leaves.
        oldest_ms: i64,
    },
}

/// A recorded submission.
#[derive(Debug, Clone, PartialEq)]
pub struct Submission {
    /// Its id.
    pub id: String,
    /// The revision it was graded against.
    pub revision: i64,
    /// The student.
    pub student: String,
    /// When it was recorded (ms since the epoch).
    pub submitted_ms: i64,
    /// The graded result (JSON).
    pub result: String,
    /// The score.
    pub score: f64,
}

impl Store {
    /// The live revision of assignment `id` (0: none, or deleted).
    async fn current_revision(&self, id: &str) -> Result<i64, StoreError> {
        let row = sqlx::query(
            "SELECT revision, deleted_ms FROM assignments WHERE id = $1 \
             ORDER BY revision DESC LIMIT 1",
        )
        .bind(id)
        .fetch_optional(self.pool())
        .await?;
        Ok(match row {
            Some(r) if r.try_get::<Option<i64>, _>("deleted_ms")?.is_none() => {
                r.try_get("revision")?
            }
            _ => 0,
        })
    }

    /// Stores `document` as the next revision of `id` and says which. With `expected`,
    /// only if the live revision is that one (0: none yet), else a conflict.
    pub async fn put_assignment(
        &self,
        id: &str,
        document: &str,
        expected: Option<i64>,
    ) -> Result<Put, PutError> {
        let current = self.current_revision(id).await?;
        if let Some(expected) = expected
            && expected != current
        {
            return Err(PutError::Conflict { expected, current });
        }
        // Revisions keep counting past a deletion, so that no two documents share one.
        let last: (Option<i64>,) =
            sqlx::query_as("SELECT MAX(revision) FROM assignments WHERE id = $1")
                .bind(id)
                .fetch_one(self.pool())
                .await
                .map_err(StoreError::from)?;
        let revision = last.0.unwrap_or(0) + 1;
        let inserted = sqlx::query(
            "INSERT INTO assignments (id, revision, document, created_ms) VALUES ($1, $2, $3, $4)",
        )
        .bind(id)
        .bind(revision)
        .bind(document)
        .bind(now_ms())
        .execute(self.pool())
        .await;
        match inserted {
            Ok(_) => Ok(Put {
                revision,
                created: current == 0,
            }),
            // Another writer took this revision first (the primary key decides).
            Err(sqlx::Error::Database(e)) if e.is_unique_violation() => Err(PutError::Conflict {
                expected: expected.unwrap_or(current),
                current: self.current_revision(id).await?,
            }),
            Err(e) => Err(StoreError::from(e).into()),
        }
    }

    /// The live revision of assignment `id`, or `None` if there is none (or it was deleted).
    pub async fn assignment(&self, id: &str) -> Result<Option<StoredAssignment>, StoreError> {
        let row = sqlx::query(
            "SELECT revision, document, deleted_ms FROM assignments WHERE id = $1 \
             ORDER BY revision DESC LIMIT 1",
        )
        .bind(id)
        .fetch_optional(self.pool())
        .await?;
        let Some(row) = row else { return Ok(None) };
        if row.try_get::<Option<i64>, _>("deleted_ms")?.is_some() {
            return Ok(None);
        }
        Ok(Some(StoredAssignment {
            revision: row.try_get("revision")?,
            document: row.try_get("document")?,
        }))
    }

    /// Every live assignment at its latest revision, by id.
    pub async fn live_assignments(&self) -> Result<Vec<ListedAssignment>, StoreError> {
        let rows = sqlx::query(
            "SELECT a.id, a.revision, a.document FROM assignments a \
             WHERE a.deleted_ms IS NULL \
             AND a.revision = (SELECT MAX(b.revision) FROM assignments b WHERE b.id = a.id) \
             ORDER BY a.id",
        )
        .fetch_all(self.pool())
        .await?;
        rows.iter()
            .map(|r| {
                Ok(ListedAssignment {
                    id: r.try_get("id")?,
                    stored: StoredAssignment {
                        revision: r.try_get("revision")?,
                        document: r.try_get("document")?,
                    },
                })
            })
            .collect()
    }

    /// Deletes assignment `id` (its submissions stay) and revokes the grader tokens
    /// scoped to it, in one transaction, so that they do not come back to life if the
    /// id is used again; whether it existed.
    pub async fn delete_assignment(&self, id: &str) -> Result<bool, StoreError> {
        let now = now_ms();
        let mut tx = self.pool().begin().await?;
        let done = sqlx::query(
            "UPDATE assignments SET deleted_ms = $1 WHERE id = $2 AND deleted_ms IS NULL",
        )
        .bind(now)
        .bind(id)
        .execute(&mut *tx)
        .await?;
        let existed = done.rows_affected() > 0;
        if existed {
            sqlx::query(
                "UPDATE tokens SET revoked_ms = $1 \
                 WHERE role = 'grader' AND assignment_id = $2 AND revoked_ms IS NULL",
            )
            .bind(now)
            .bind(id)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(existed)
    }

    /// When `student`'s most recent submissions to `assignment` since `since_ms` were
    /// recorded (ms since the epoch), newest first, at most `limit` of them: what a
    /// rate limit counts, from the store, so that every replica counts the same.
    pub async fn recent_submission_times(
        &self,
        assignment: &str,
        student: &str,
        since_ms: i64,
        limit: u32,
    ) -> Result<Vec<i64>, StoreError> {
        let rows = sqlx::query(
            "SELECT submitted_ms FROM submissions \
             WHERE assignment_id = $1 AND student = $2 AND submitted_ms > $3 \
             ORDER BY submitted_ms DESC LIMIT $4",
        )
        .bind(assignment)
        .bind(student)
        .bind(since_ms)
        .bind(i64::from(limit))
        .fetch_all(self.pool())
        .await?;
        rows.iter()
            .map(|r| r.try_get("submitted_ms").map_err(StoreError::from))
            .collect()
    }

    /// Records a submission, committed when this returns. A second one with the same
    /// idempotency key for the same assignment is not recorded: the first is returned,
    /// with `false`.
    pub async fn record_submission(
        &self,
        s: &NewSubmission<'_>,
    ) -> Result<(Submission, bool), StoreError> {
        match self.record_submission_within(s, None).await? {
            Recorded::New(sub) => Ok((sub, true)),
            Recorded::Existing(sub) => Ok((sub, false)),
            Recorded::Limited { .. } => Err(StoreError::Corrupt(
                "a submission without a limit was refused by one".into(),
            )),
        }
    }

    /// [`Store::record_submission`] within `window`, if there is one: the count and the
    /// insert are one statement (SQLite runs statements one at a time; on PostgreSQL a
    /// transaction lock per student and assignment orders them), so concurrent
    /// submissions cannot together pass the limit.
    pub async fn record_submission_within(
        &self,
        s: &NewSubmission<'_>,
        window: Option<Window>,
    ) -> Result<Recorded, StoreError> {
        if let Some(key) = s.idempotency_key
            && let Some(existing) = self.submission_by_key(s.assignment, key).await?
        {
            return Ok(Recorded::Existing(existing));
        }
        let id = hex::encode(random_bytes::<16>()?);
        let submitted_ms = now_ms();
        let mut tx = self.pool().begin().await?;
        // No window: one that starts after every time there is, so it counts nothing.
        let (since_ms, limit) = window.map_or((i64::MAX, 1), |w| (w.since_ms, i64::from(w.limit)));
        if window.is_some() && self.backend() == super::Backend::Postgres {
            sqlx::query("SELECT pg_advisory_xact_lock(hashtext($1))")
                .bind(format!("submissions\n{}\n{}", s.assignment, s.student))
                .execute(&mut *tx)
                .await?;
        }
        let inserted = sqlx::query(
            "INSERT INTO submissions (id, assignment_id, revision, student, idempotency_key, \
             submitted_ms, result, score) \
             SELECT $1, $2, $3, $4, $5, $6, $7, $8 \
             WHERE (SELECT COUNT(*) FROM submissions \
                    WHERE assignment_id = $2 AND student = $4 AND submitted_ms > $9) < $10",
        )
        .bind(&id)
        .bind(s.assignment)
        .bind(s.revision)
        .bind(s.student)
        .bind(s.idempotency_key)
        .bind(submitted_ms)
        .bind(s.result)
        .bind(s.score)
        .bind(since_ms)
        .bind(limit)
        .execute(&mut *tx)
        .await;
        match (inserted, s.idempotency_key) {
            (Ok(done), _) if done.rows_affected() > 0 => {
                tx.commit().await?;
                Ok(Recorded::New(Submission {
                    id,
                    revision: s.revision,
                    student: s.student.to_owned(),
                    submitted_ms,
                    result: s.result.to_owned(),
                    score: s.score,
                }))
            }
            (Ok(_), _) => {
                tx.rollback().await?;
                let limit = window.map_or(0, |w| w.limit);
                let times = self
                    .recent_submission_times(s.assignment, s.student, since_ms, limit)
                    .await?;
                Ok(Recorded::Limited {
                    oldest_ms: times.last().copied().unwrap_or(submitted_ms),
                })
            }
            // A concurrent retry with the same key committed first: return its row.
            (Err(sqlx::Error::Database(e)), Some(key)) if e.is_unique_violation() => {
                tx.rollback().await?;
                let existing = self.submission_by_key(s.assignment, key).await?;
                existing
                    .map(Recorded::Existing)
                    .ok_or_else(|| StoreError::Corrupt("a conflicting key without its row".into()))
            }
            (Err(e), _) => Err(e.into()),
        }
    }

    /// The submission recorded for `assignment` under the idempotency key `key`.
    pub async fn submission_by_key(
        &self,
        assignment: &str,
        key: &str,
    ) -> Result<Option<Submission>, StoreError> {
        self.submission_where(assignment, "idempotency_key", key)
            .await
    }

    /// Submission `id` of `assignment`, if it has one by that id.
    pub async fn submission(
        &self,
        assignment: &str,
        id: &str,
    ) -> Result<Option<Submission>, StoreError> {
        self.submission_where(assignment, "id", id).await
    }

    /// The submission of `assignment` whose `column` (a unique one: `id`,
    /// `idempotency_key`) is `value`.
    async fn submission_where(
        &self,
        assignment: &str,
        column: &'static str,
        value: &str,
    ) -> Result<Option<Submission>, StoreError> {
        let sql = format!(
            "SELECT id, revision, student, submitted_ms, result, score FROM submissions \
             WHERE assignment_id = $1 AND {column} = $2"
        );
        let row = sqlx::query(&sql)
            .bind(assignment)
            .bind(value)
            .fetch_optional(self.pool())
            .await?;
        row.map(|r| submission(&r)).transpose()
    }

    /// The submissions of an assignment, oldest first; only `student`'s with one.
    pub async fn submissions(
        &self,
        assignment: &str,
        student: Option<&str>,
    ) -> Result<Vec<Submission>, StoreError> {
        let rows = sqlx::query(
            "SELECT id, revision, student, submitted_ms, result, score FROM submissions \
             WHERE assignment_id = $1 AND ($2 IS NULL OR student = $2) \
             ORDER BY submitted_ms, id",
        )
        .bind(assignment)
        .bind(student)
        .fetch_all(self.pool())
        .await?;
        rows.iter().map(submission).collect()
    }
}

fn submission(r: &sqlx::any::AnyRow) -> Result<Submission, StoreError> {
    Ok(Submission {
        id: r.try_get("id")?,
        revision: r.try_get("revision")?,
        student: r.try_get("student")?,
        submitted_ms: r.try_get("submitted_ms")?,
        result: r.try_get("result")?,
        score: r.try_get("score")?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Revisions, conflicts, deletion and idempotent submissions, on any backend.
    async fn round_trip(store: &Store) {
        // A fresh id per run: the PostgreSQL database outlives a test run.
        let id = format!("a-{}", hex::encode(random_bytes::<6>().unwrap()));
        assert_eq!(store.assignment(&id).await.unwrap(), None);
        let put = |doc: &'static str, expected| {
            let id = id.clone();
            async move { store.put_assignment(&id, doc, expected).await.unwrap() }
        };
        assert_eq!(
            put("{\"v\":1}", Some(0)).await,
            Put {
                revision: 1,
                created: true
            }
        );
        assert_eq!(
            put("{\"v\":2}", None).await,
            Put {
                revision: 2,
                created: false
            }
        );
        let e = store.put_assignment(&id, "{}", Some(1)).await.unwrap_err();
        assert!(
            matches!(
                e,
                PutError::Conflict {
                    expected: 1,
                    current: 2
                }
            ),
            "{e}"
        );
        let a = store.assignment(&id).await.unwrap().unwrap();
        assert_eq!((a.revision, a.document.as_str()), (2, "{\"v\":2}"));

        let new = |student, key| NewSubmission {
            assignment: &id,
            revision: 2,
            student,
            idempotency_key: key,
            result: "{\"score\":7.5}",
            score: 7.5,
        };
        let (first, fresh) = store
            .record_submission(&new("s1", Some("k1")))
            .await
            .unwrap();
        assert!(fresh);
        let (again, fresh) = store
            .record_submission(&new("s1", Some("k1")))
            .await
            .unwrap();
        assert!(!fresh);
        assert_eq!(again, first);
        store.record_submission(&new("s1", None)).await.unwrap();
        store.record_submission(&new("s1", None)).await.unwrap();
        store
            .record_submission(&new("s2", Some("k2")))
            .await
            .unwrap();
        assert_eq!(store.submissions(&id, None).await.unwrap().len(), 4);
        let s1 = store.submissions(&id, Some("s1")).await.unwrap();
        assert_eq!(s1.len(), 3);
        assert!(s1.iter().all(|s| s.student == "s1" && s.score == 7.5));
        let times = store
            .recent_submission_times(&id, "s1", 0, 2)
            .await
            .unwrap();
        assert_eq!(times.len(), 2);
        assert!(times[0] >= times[1], "newest first: {times:?}");
        let all = store
            .recent_submission_times(&id, "s1", 0, 10)
            .await
            .unwrap();
        assert_eq!(all.len(), 3);
        let later = store
            .recent_submission_times(&id, "s1", now_ms() + 1000, 10)
            .await
            .unwrap();
        assert!(later.is_empty());
        // Within a window: the limit counts what the window holds, a replay is not
        // recorded again, and a full window records nothing.
        let window = Window {
            limit: 4,
            since_ms: 0,
        };
        let r = store
            .record_submission_within(&new("s1", Some("k3")), Some(window))
            .await
            .unwrap();
        let Recorded::New(fourth) = r else {
            panic!("{r:?}")
        };
        let r = store
            .record_submission_within(&new("s1", Some("k3")), Some(window))
            .await
            .unwrap();
        assert_eq!(r, Recorded::Existing(fourth));
        let r = store
            .record_submission_within(&new("s1", None), Some(window))
            .await
            .unwrap();
        let oldest = store.submissions(&id, Some("s1")).await.unwrap()[0].submitted_ms;
        assert_eq!(r, Recorded::Limited { oldest_ms: oldest });
        let r = store
            .record_submission_within(&new("s2", None), Some(window))
            .await
            .unwrap();
        assert!(matches!(r, Recorded::New(_)), "{r:?}");
        assert_eq!(store.submissions(&id, Some("s1")).await.unwrap().len(), 4);
        let listed = store.live_assignments().await.unwrap();
        let mine = listed.iter().find(|l| l.id == id).unwrap();
        assert_eq!(mine.stored.revision, 2);

        let grader = store
            .create_token(super::super::Role::Grader, Some(&id))
            .await
            .unwrap();
        let other = store
            .create_token(super::super::Role::Grader, Some("another"))
            .await
            .unwrap();
        assert!(store.delete_assignment(&id).await.unwrap());
        assert!(!store.delete_assignment(&id).await.unwrap());
        assert_eq!(store.assignment(&id).await.unwrap(), None);
        assert!(
            !store
                .live_assignments()
                .await
                .unwrap()
                .iter()
                .any(|l| l.id == id)
        );
        // Its grader tokens went with it, and stay gone; others stay.
        assert_eq!(
            store.authenticate(grader.token.expose()).await.unwrap(),
            None
        );
        assert!(
            store
                .authenticate(other.token.expose())
                .await
                .unwrap()
                .is_some()
        );
        // After a deletion the id starts again from nothing, at a revision never used.
        assert_eq!(
            put("{}", Some(0)).await,
            Put {
                revision: 3,
                created: true
            }
        );
        assert_eq!(
            store.authenticate(grader.token.expose()).await.unwrap(),
            None
        );
    }

    #[tokio::test]
    async fn assignments_and_submissions_round_trip_on_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        round_trip(&Store::open_dir(dir.path()).await.unwrap()).await;
    }

    #[tokio::test]
    #[ignore = "needs PostgreSQL: run .ci/test-all"]
    async fn assignments_and_submissions_round_trip_on_postgres() {
        let url = super::super::tests::postgres_url()
            .expect("RAYTILE_TEST_DATABASE_URL names a PostgreSQL database");
        round_trip(&Store::connect(&url).await.unwrap()).await;
    }
}
