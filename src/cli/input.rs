//! What the commands read: a scene file (or standard input, `-`), and a scene's errors
//! as the command line reports them, naming the file. Shared by the local commands,
//! `render --servers` and `trace`/`grade`.

use std::io::Read;
use std::path::Path;

use anyhow::Context;

use crate::scene::{self, Limits, Scene, SceneError};

/// Reads a scene file (or standard input) and validates it, without limits.
pub fn load_scene(path: &Path) -> anyhow::Result<Scene> {
    let bytes = read_input(path)?;
    scene::parse(&bytes, &Limits::NONE).map_err(|e| scene_error(path, e))
}

/// The bytes of a scene file, or of standard input for `-`.
pub(super) fn read_input(path: &Path) -> anyhow::Result<Vec<u8>> {
    if path == Path::new("-") {
        let mut b = Vec::new();
        std::io::stdin()
            .read_to_end(&mut b)
            .context("cannot read the scene from standard input")?;
        Ok(b)
    } else {
        std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))
    }
}

/// A scene error as the command line reports it, naming the file.
pub(super) fn scene_error(path: &Path, e: SceneError) -> anyhow::Error {
    match &e {
        SceneError::Syntax { .. } => anyhow::anyhow!("{}: {e}", path.display()),
        SceneError::Invalid(problems) => {
            let list: Vec<String> = problems.iter().map(|p| format!("  {p}")).collect();
            anyhow::anyhow!(
                "{}: the scene is invalid:\n{}",
                path.display(),
                list.join("\n")
            )
        }
    }
}
