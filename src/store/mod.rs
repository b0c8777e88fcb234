//! The database: bearer tokens now, assignments and submissions next. Embedded SQLite
//! in the data folder by default (created on first use), PostgreSQL when
//! `--database` names one, so that every replica shares it.
//!
//! Both backends go through sqlx's `Any` driver: one schema (`migrations/`, embedded in
//! the binary and applied at open) and one set of queries, written in the SQL both
//! speak (`$1` placeholders, which SQLite reads as numbered parameters too).

pub mod assignments;
pub mod grades;
pub mod tokens;

use std::borrow::Cow;
use std::path::Path;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use sqlx::AnyPool;
use sqlx::any::AnyPoolOptions;
use sqlx::migrate::{Migration, MigrationType, Migrator};

pub use tokens::{CreatedToken, Principal, Role, Secret};

/// The embedded SQLite database's file name inside the data folder.
pub const SQLITE_FILE: &str = "raytile.db";

/// Connections in the pool: the store's queries are short, and SQLite has one writer.
const MAX_CONNECTIONS: u32 = 8;

/// How long a request waits for a free connection before it fails.
const ACQUIRE_TIMEOUT: Duration = Duration::from_secs(10);

/// The schema's migrations, in order, embedded in the binary.
const MIGRATIONS: &[(i64, &str, &str)] = &[(
    1,
    "tokens assignments submissions",
    include_str!("migrations/0001_tokens_assignments_submissions.sql"),
)];

/// Why the store could not do something.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// The data folder could not be created or read.
    #[error("cannot use the data folder {path}: {source}")]
    DataDir {
        /// The folder.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The database URL is neither `postgres://…` nor `sqlite:…`.
    #[error("unsupported database URL (use postgres://… or sqlite:…)")]
    UnsupportedUrl,
    /// A migration failed.
    #[error("cannot migrate the database: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    /// A query failed.
    #[error("database error: {0}")]
    Database(#[from] sqlx::Error),
    /// The operating system's random number generator failed.
    #[error("no randomness from the operating system: {0}")]
    Random(getrandom::Error),
    /// A row holds what the schema does not allow.
    #[error("corrupt row: {0}")]
    Corrupt(String),
}

/// Which database the store talks to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// Embedded SQLite.
    Sqlite,
    /// A PostgreSQL server.
    Postgres,
}

/// The database, migrated and ready; cheap to clone (a pool).
#[derive(Debug, Clone)]
pub struct Store {
    pool: AnyPool,
    backend: Backend,
}

impl Store {
    /// Opens the store `database` names, else (with `None`) SQLite in `data_dir`: what
    /// `--database` and `--data-dir` say (`config::StoreArgs::open`).
    pub async fn open(database: Option<&Secret>, data_dir: &Path) -> Result<Store, StoreError> {
        match database {
            Some(url) => Store::connect(url.expose()).await,
            None => Store::open_dir(data_dir).await,
        }
    }

    /// Opens (creating on first use) the embedded SQLite database in `dir`.
    pub async fn open_dir(dir: &Path) -> Result<Store, StoreError> {
        let io = |source| StoreError::DataDir {
            path: dir.display().to_string(),
            source,
        };
        std::fs::create_dir_all(dir).map_err(io)?;
        let dir = dir.canonicalize().map_err(io)?;
        let path = dir.join(SQLITE_FILE);
        let path = path
            .to_str()
            .filter(|p| !p.contains(['?', '#']))
            .ok_or_else(|| {
                io(std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    "the path must be UTF-8 without `?` or `#`",
                ))
            })?;
        Store::connect(&format!("sqlite://{path}?mode=rwc")).await
    }

    /// Connects to `url` (`postgres://…`, `postgresql://…` or `sqlite:…`) and applies the
    /// migrations it lacks.
    pub async fn connect(url: &str) -> Result<Store, StoreError> {
        sqlx::any::install_default_drivers();
        let backend = if url.starts_with("postgres://") || url.starts_with("postgresql://") {
            Backend::Postgres
        } else if url.starts_with("sqlite:") {
            Backend::Sqlite
        } else {
            return Err(StoreError::UnsupportedUrl);
        };
        let pool = AnyPoolOptions::new()
            .max_connections(MAX_CONNECTIONS)
            .acquire_timeout(ACQUIRE_TIMEOUT)
            .connect(url)
            .await?;
        if backend == Backend::Sqlite {
            // WAL lets `raytile token create` write while the server reads (and waits
            // out the server's writes: sqlx gives SQLite a 5 s busy timeout). The mode
            // is kept in the file, so setting it once per open is enough.
            sqlx::query("PRAGMA journal_mode = WAL")
                .execute(&pool)
                .await?;
        }
        migrator().run(&pool).await?;
        Ok(Store { pool, backend })
    }

    /// Which database this is.
    pub fn backend(&self) -> Backend {
        self.backend
    }

    /// The connection pool, for the store's own modules.
    pub(crate) fn pool(&self) -> &AnyPool {
        &self.pool
    }

    /// Closes every connection (what a short-lived command does before it exits).
    pub async fn close(&self) {
        self.pool.close().await;
    }
}

/// The embedded migrations as sqlx runs them.
fn migrator() -> Migrator {
    let migrations = MIGRATIONS
        .iter()
        .map(|&(version, description, sql)| {
            Migration::new(
                version,
                Cow::Borrowed(description),
                MigrationType::Simple,
                Cow::Borrowed(sql),
                false,
            )
        })
        .collect::<Vec<_>>();
    Migrator {
        migrations: Cow::Owned(migrations),
        ..Migrator::DEFAULT
    }
}

/// Now, in milliseconds since the Unix epoch (the schema's times).
pub(crate) fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

/// `n` random bytes from the operating system.
pub(crate) fn random_bytes<const N: usize>() -> Result<[u8; N], StoreError> {
    let mut b = [0u8; N];
    getrandom::fill(&mut b).map_err(StoreError::Random)?;
    Ok(b)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The PostgreSQL database the tests may use: `RAYTILE_TEST_DATABASE_URL`.
    pub(crate) fn postgres_url() -> Option<String> {
        std::env::var("RAYTILE_TEST_DATABASE_URL")
            .ok()
            .filter(|u| !u.is_empty())
    }

    #[tokio::test]
    async fn sqlite_is_created_on_first_use_and_reopens_migrated() {
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("nested/data");
        let store = Store::open_dir(&data).await.unwrap();
        assert_eq!(store.backend(), Backend::Sqlite);
        assert!(data.join(SQLITE_FILE).is_file());
        let mode: (String,) = sqlx::query_as("PRAGMA journal_mode")
            .fetch_one(store.pool())
            .await
            .unwrap();
        assert_eq!(mode.0, "wal");
        store.close().await;
        // A second open finds the schema applied and applies nothing twice.
        let again = Store::open_dir(&data).await.unwrap();
        let n: (i64,) = sqlx::query_as("SELECT COUNT(*) FROM _sqlx_migrations")
            .fetch_one(again.pool())
            .await
            .unwrap();
        assert_eq!(n.0, MIGRATIONS.len() as i64);
    }

    #[tokio::test]
    async fn other_urls_are_refused() {
        let e = Store::connect("mysql://localhost/x").await.unwrap_err();
        assert!(matches!(e, StoreError::UnsupportedUrl), "{e}");
    }
}
