//! The command line as a user runs it.

use crate::support::*;

#[test]
fn validate_accepts_every_shipped_scene() {
    for entry in std::fs::read_dir(scene("")).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().is_some_and(|e| e == "json") {
            let out = run(&["validate", p.to_str().unwrap()]);
            assert!(
                out.status.success(),
                "{}: {}",
                p.display(),
                String::from_utf8_lossy(&out.stdout)
            );
        }
    }
}
