//! Bearer tokens: 256 random bits from the operating system, shown once when created,
//! kept only as their SHA-256. A presented token is found by its hash and the stored
//! hash is compared again in constant time, so neither the lookup nor the comparison
//! times a guess against a secret.

use std::fmt;
use std::str::FromStr;

use sha2::{Digest, Sha256};
use sqlx::Row;
use subtle::ConstantTimeEq;

use super::{Store, StoreError, now_ms, random_bytes};

/// What every token starts with, so that secret scanners recognise a leaked one.
pub const TOKEN_PREFIX: &str = "rt_";

/// What a token may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Manage assignments, read submissions and grades, render anything.
    Instructor,
    /// Fetch the scenes of its assignment and submit for grading, nothing else.
    Grader,
}

impl Role {
    /// The name in the database and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Instructor => "instructor",
            Role::Grader => "grader",
        }
    }
}

impl FromStr for Role {
    type Err = String;
    fn from_str(s: &str) -> Result<Role, String> {
        match s {
            "instructor" => Ok(Role::Instructor),
            "grader" => Ok(Role::Grader),
            other => Err(format!("unknown role `{other}` (instructor or grader)")),
        }
    }
}

/// A secret (a token, a database URL with a password) whose `Debug` does not show it,
/// so that no log line or panic message carries it.
#[derive(Clone, PartialEq, Eq)]
pub struct Secret(String);

impl Secret {
    /// Wraps `s`.
    pub fn new(s: impl Into<String>) -> Secret {
        Secret(s.into())
    }

    /// The secret itself, for the one place that needs it.
    pub fn expose(&self) -> &str {
        &self.0
    }
}

impl fmt::Debug for Secret {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Secret(…)")
    }
}

impl FromStr for Secret {
    type Err = std::convert::Infallible;
    fn from_str(s: &str) -> Result<Secret, Self::Err> {
        Ok(Secret(s.to_string()))
    }
}

/// A token just created: the only time its secret is known.
#[derive(Debug, Clone)]
pub struct CreatedToken {
    /// The public id (for listing and revoking).
    pub id: String,
    /// The token to hand over.
    pub token: Secret,
}

/// Who a valid token speaks for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Principal {
    /// The token's id (`admin` for `RAYTILE_ADMIN_TOKEN`).
    pub id: String,
    /// Its role.
    pub role: Role,
    /// The assignment it is scoped to; `None`: every one.
    pub assignment: Option<String>,
}

/// The SHA-256 of a token.
pub fn hash_token(token: &str) -> [u8; 32] {
    Sha256::digest(token.as_bytes()).into()
}

/// Whether two hashes are equal, in time that does not depend on where they differ.
pub fn hashes_equal(a: &[u8], b: &[u8]) -> bool {
    a.ct_eq(b).into()
}

/// A new random token: the prefix and 32 bytes from the OS, in hex.
pub fn generate_token() -> Result<Secret, StoreError> {
    let bytes: [u8; 32] = random_bytes()?;
    Ok(Secret(format!("{TOKEN_PREFIX}{}", hex::encode(bytes))))
}

impl Store {
    /// Creates a token for `role` (a grader scoped to `assignment`, or to every one) and
    /// returns it; only its hash is stored.
    pub async fn create_token(
        &self,
        role: Role,
        assignment: Option<&str>,
    ) -> Result<CreatedToken, StoreError> {
        let id = hex::encode(random_bytes::<8>()?);
        let token = generate_token()?;
        sqlx::query(
            "INSERT INTO tokens (id, role, assignment_id, hash, created_ms) \
             VALUES ($1, $2, $3, $4, $5)",
        )
        .bind(&id)
        .bind(role.as_str())
        .bind(assignment)
        .bind(hex::encode(hash_token(token.expose())))
        .bind(now_ms())
        .execute(self.pool())
        .await?;
        Ok(CreatedToken { id, token })
    }

    /// Who `token` speaks for: `None` when it is unknown or revoked.
    pub async fn authenticate(&self, token: &str) -> Result<Option<Principal>, StoreError> {
        let hash = hash_token(token);
        let row = sqlx::query(
            "SELECT id, role, assignment_id, hash FROM tokens \
             WHERE hash = $1 AND revoked_ms IS NULL",
        )
        .bind(hex::encode(hash))
        .fetch_optional(self.pool())
        .await?;
        let Some(row) = row else { return Ok(None) };
        let stored: String = row.try_get("hash")?;
        let stored = hex::decode(stored).map_err(|e| StoreError::Corrupt(e.to_string()))?;
        if !hashes_equal(&stored, &hash) {
            return Ok(None);
        }
        let role: String = row.try_get("role")?;
        Ok(Some(Principal {
            id: row.try_get("id")?,
            role: role.parse().map_err(StoreError::Corrupt)?,
            assignment: row.try_get("assignment_id")?,
        }))
    }

    /// Revokes the token with this id; whether there was one still valid.
    pub async fn revoke_token(&self, id: &str) -> Result<bool, StoreError> {
        let done =
            sqlx::query("UPDATE tokens SET revoked_ms = $1 WHERE id = $2 AND revoked_ms IS NULL")
                .bind(now_ms())
                .bind(id)
                .execute(self.pool())
                .await?;
        Ok(done.rows_affected() > 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_is_256_random_bits_and_hashes_to_sha256() {
        let a = generate_token().unwrap();
        let b = generate_token().unwrap();
        assert_ne!(a, b);
        let hex_part = a.expose().strip_prefix(TOKEN_PREFIX).unwrap();
        assert_eq!(hex_part.len(), 64);
        assert!(hex_part.bytes().all(|c| c.is_ascii_hexdigit()));
        // SHA-256 of "abc" (FIPS 180-2, appendix B.1).
        assert_eq!(
            hex::encode(hash_token("abc")),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn hashes_compare_whole() {
        let h = hash_token("x");
        assert!(hashes_equal(&h, &hash_token("x")));
        assert!(!hashes_equal(&h, &hash_token("y")));
        assert!(!hashes_equal(&h, &h[..31]));
        assert!(!hashes_equal(&h, &[]));
    }

    #[test]
    fn secrets_stay_out_of_debug_output() {
        let t = generate_token().unwrap();
        let shown = format!(
            "{:?}",
            CreatedToken {
                id: "i".into(),
                token: t.clone()
            }
        );
        assert!(!shown.contains(t.expose()), "{shown}");
    }

    /// Create, authenticate, revoke: what every backend must do alike.
    async fn round_trip(store: &Store) {
        let instructor = store.create_token(Role::Instructor, None).await.unwrap();
        let grader = store
            .create_token(Role::Grader, Some("ray-casting"))
            .await
            .unwrap();
        let who = store.authenticate(instructor.token.expose()).await.unwrap();
        assert_eq!(
            who,
            Some(Principal {
                id: instructor.id.clone(),
                role: Role::Instructor,
                assignment: None
            })
        );
        let who = store
            .authenticate(grader.token.expose())
            .await
            .unwrap()
            .unwrap();
        assert_eq!(who.role, Role::Grader);
        assert_eq!(who.assignment.as_deref(), Some("ray-casting"));
        // The token itself is nowhere in the table.
        let rows = sqlx::query("SELECT hash FROM tokens")
            .fetch_all(store.pool())
            .await
            .unwrap();
        for r in rows {
            let h: String = r.get("hash");
            assert!(!h.contains(instructor.token.expose()) && h.len() == 64);
        }
        assert_eq!(store.authenticate("rt_nonsense").await.unwrap(), None);
        assert_eq!(store.authenticate("").await.unwrap(), None);
        assert!(store.revoke_token(&grader.id).await.unwrap());
        assert!(!store.revoke_token(&grader.id).await.unwrap());
        assert_eq!(
            store.authenticate(grader.token.expose()).await.unwrap(),
            None
        );
        assert!(
            store
                .authenticate(instructor.token.expose())
                .await
                .unwrap()
                .is_some()
        );
    }

    #[tokio::test]
    async fn tokens_round_trip_on_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open_dir(dir.path()).await.unwrap();
        round_trip(&store).await;
    }

    #[tokio::test]
    #[ignore = "needs PostgreSQL: run .ci/test-all"]
    async fn tokens_round_trip_on_postgres() {
        let url = super::super::tests::postgres_url()
            .expect("RAYTILE_TEST_DATABASE_URL names a PostgreSQL database");
        let store = Store::connect(&url).await.unwrap();
        assert_eq!(store.backend(), super::super::Backend::Postgres);
        round_trip(&store).await;
    }
}
