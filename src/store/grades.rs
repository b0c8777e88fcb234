//! What the gradebook reads: every submission's score without its result (the results
//! are the bulk of the table, and a gradebook row needs one of them per student), and
//! the results of the submissions chosen. The choosing itself is
//! `assignment::gradebook::pick`'s; the rest of the submissions' queries are in
//! [`super::assignments`].

use sqlx::Row;

use super::{Store, StoreError};

/// How many ids one `IN (…)` list binds: far below SQLite's limit on parameters
/// (32766) and PostgreSQL's (65535).
const IDS_PER_QUERY: usize = 500;

/// A submission's score, without its result.
#[derive(Debug, Clone, PartialEq)]
pub struct Score {
    /// The submission's id.
    pub id: String,
    /// The student.
    pub student: String,
    /// When it was recorded (ms since the epoch).
    pub submitted_ms: i64,
    /// The score.
    pub score: f64,
}

impl Store {
    /// The scores of every submission of `assignment`, by student, then oldest first.
    pub async fn scores(&self, assignment: &str) -> Result<Vec<Score>, StoreError> {
        let rows = sqlx::query(
            "SELECT id, student, submitted_ms, score FROM submissions \
             WHERE assignment_id = $1 ORDER BY student, submitted_ms, id",
        )
        .bind(assignment)
        .fetch_all(self.pool())
        .await?;
        rows.iter()
            .map(|r| {
                Ok(Score {
                    id: r.try_get("id")?,
                    student: r.try_get("student")?,
                    submitted_ms: r.try_get("submitted_ms")?,
                    score: r.try_get("score")?,
                })
            })
            .collect()
    }

    /// The stored results (JSON) of the submissions of `assignment` with these `ids`,
    /// as `(id, result)` in no particular order; ids it does not have are left out.
    pub async fn results(
        &self,
        assignment: &str,
        ids: &[&str],
    ) -> Result<Vec<(String, String)>, StoreError> {
        let mut out = Vec::with_capacity(ids.len());
        for chunk in ids.chunks(IDS_PER_QUERY) {
            let marks: Vec<String> = (2..chunk.len() + 2).map(|i| format!("${i}")).collect();
            let sql = format!(
                "SELECT id, result FROM submissions WHERE assignment_id = $1 AND id IN ({})",
                marks.join(", ")
            );
            let mut q = sqlx::query(&sql).bind(assignment);
            for id in chunk {
                q = q.bind(*id);
            }
            for r in q.fetch_all(self.pool()).await? {
                out.push((r.try_get("id")?, r.try_get("result")?));
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::super::assignments::NewSubmission;
    use super::super::random_bytes;
    use super::*;

    /// Scores in order and results by id, on any backend.
    async fn gradebook_queries(store: &Store) {
        // A fresh id per run: the PostgreSQL database outlives a test run.
        let id = format!("g-{}", hex::encode(random_bytes::<6>().unwrap()));
        let other = format!("{id}-other");
        store.put_assignment(&id, "{}", None).await.unwrap();
        let mut recorded = Vec::new();
        for (student, score) in [("zoe", 3.0), ("amy", 9.5), ("zoe", 7.0)] {
            let result = format!("{{\"score\":{score}}}");
            let (s, _) = store
                .record_submission(&NewSubmission {
                    assignment: &id,
                    revision: 1,
                    student,
                    idempotency_key: None,
                    result: &result,
                    score,
                })
                .await
                .unwrap();
            recorded.push(s);
            // Distinct times, so that the order by time is the order of recording.
            tokio::time::sleep(std::time::Duration::from_millis(3)).await;
        }
        store
            .record_submission(&NewSubmission {
                assignment: &other,
                revision: 1,
                student: "amy",
                idempotency_key: None,
                result: "{}",
                score: 1.0,
            })
            .await
            .unwrap();

        let scores = store.scores(&id).await.unwrap();
        let seen: Vec<(&str, f64)> = scores
            .iter()
            .map(|s| (s.student.as_str(), s.score))
            .collect();
        assert_eq!(seen, [("amy", 9.5), ("zoe", 3.0), ("zoe", 7.0)]);
        assert_eq!(scores[1].id, recorded[0].id);
        assert_eq!(scores[1].submitted_ms, recorded[0].submitted_ms);
        assert!(store.scores("no-such-assignment").await.unwrap().is_empty());

        // Another assignment's submission is not this one's, even by its id.
        let theirs = store.submissions(&other, None).await.unwrap();
        let ids = [
            recorded[2].id.as_str(),
            recorded[1].id.as_str(),
            theirs[0].id.as_str(),
            "no-such-id",
        ];
        let mut results = store.results(&id, &ids).await.unwrap();
        results.sort();
        let mut expected = vec![
            (recorded[1].id.clone(), "{\"score\":9.5}".to_owned()),
            (recorded[2].id.clone(), "{\"score\":7}".to_owned()),
        ];
        expected.sort();
        assert_eq!(results, expected);
        assert!(store.results(&id, &[]).await.unwrap().is_empty());

        // More ids than one query binds.
        let many: Vec<String> = (0..IDS_PER_QUERY * 2 + 3)
            .map(|i| format!("none-{i}"))
            .chain([recorded[0].id.clone()])
            .collect();
        let many: Vec<&str> = many.iter().map(String::as_str).collect();
        let found = store.results(&id, &many).await.unwrap();
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].0, recorded[0].id);
    }

    #[tokio::test]
    async fn gradebook_queries_on_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        gradebook_queries(&Store::open_dir(dir.path()).await.unwrap()).await;
    }

    #[tokio::test]
    #[ignore = "needs PostgreSQL: run .ci/test-all"]
    async fn gradebook_queries_on_postgres() {
        let url = super::super::tests::postgres_url()
            .expect("RAYTILE_TEST_DATABASE_URL names a PostgreSQL database");
        gradebook_queries(&Store::connect(&url).await.unwrap()).await;
    }
}
