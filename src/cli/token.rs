//! `raytile token create`: a new bearer token, printed once on standard output. It
//! writes to the same database as the server (it may run beside it: SQLite in WAL mode
//! waits out the server's writes), so a token works as soon as it is printed.

use std::io::Write;
use std::process::ExitCode;

use anyhow::Context;

use crate::config::StoreArgs;
use crate::store::Role;

/// `raytile token …`.
#[derive(Debug, clap::Args)]
pub struct TokenArgs {
    /// What to do.
    #[command(subcommand)]
    pub command: TokenCommand,
}

/// The token subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum TokenCommand {
    /// Create a token and print it (it is shown this once; only its hash is kept).
    Create(CreateArgs),
    /// Revoke a token by its id (printed on standard error when it was created).
    Revoke(RevokeArgs),
}

/// `raytile token create`.
#[derive(Debug, clap::Args)]
pub struct CreateArgs {
    /// `instructor` (everything) or `grader` (fetch scenes and submit, nothing else).
    #[arg(long, value_parser = ["instructor", "grader"])]
    pub role: String,
    /// The assignment a grader token is scoped to (default: every assignment).
    #[arg(long)]
    pub assignment: Option<String>,
    /// Where the database is.
    #[command(flatten)]
    pub store: StoreArgs,
}

/// `raytile token revoke`.
#[derive(Debug, clap::Args)]
pub struct RevokeArgs {
    /// The token's id.
    pub id: String,
    /// Where the database is.
    #[command(flatten)]
    pub store: StoreArgs,
}

/// Runs a token subcommand.
pub fn token(args: TokenArgs) -> anyhow::Result<ExitCode> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(async {
        match args.command {
            TokenCommand::Create(a) => create(a).await,
            TokenCommand::Revoke(a) => revoke(a).await,
        }
    })
}

async fn create(a: CreateArgs) -> anyhow::Result<ExitCode> {
    let role: Role = a.role.parse().map_err(anyhow::Error::msg)?;
    if role == Role::Instructor && a.assignment.is_some() {
        anyhow::bail!("--assignment scopes grader tokens; an instructor's has every assignment");
    }
    let store = a.store.open().await.context("cannot open the database")?;
    let created = store.create_token(role, a.assignment.as_deref()).await?;
    store.close().await;
    // The token alone on standard output, so that `$(raytile token create …)` takes it;
    // the id, which is no secret, on standard error.
    let mut out = std::io::stdout().lock();
    writeln!(out, "{}", created.token.expose())?;
    out.flush()?;
    eprintln!("created {} token {}", role.as_str(), created.id);
    Ok(ExitCode::SUCCESS)
}

async fn revoke(a: RevokeArgs) -> anyhow::Result<ExitCode> {
    let store = a.store.open().await.context("cannot open the database")?;
    let revoked = store.revoke_token(&a.id).await?;
    store.close().await;
    if revoked {
        eprintln!("revoked token {}", a.id);
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!("raytile token revoke: no valid token has the id {}", a.id);
        Ok(ExitCode::from(1))
    }
}
