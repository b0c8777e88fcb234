//! The `raytile` binary: parse the command line and hand over to the library.

use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = raytile::cli::Cli::parse();
    match raytile::cli::run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("raytile: {e:#}");
            std::process::ExitCode::from(2)
        }
    }
}
