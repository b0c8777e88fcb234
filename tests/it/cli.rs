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

/// `validate` and `trace` name the sample grid in the same words, the lecture's.
#[test]
fn validate_and_trace_name_the_sample_grid_alike() {
    let dir = tempfile::tempdir().unwrap();
    for (s, want) in [(1, "1 sample per pixel"), (2, "2 × 2 samples per pixel")] {
        let bytes = std::fs::read(scene("lecture.json")).unwrap();
        let mut doc: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        doc["image"]["samples"] = s.into();
        let p = scene_file(&dir, &format!("lecture-{s}.json"), &doc);
        let out = run(&["validate", p.to_str().unwrap()]);
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.contains(&format!("5 × 5 pixels, {want}, 1 objects")),
            "{text}"
        );
        let out = run(&["trace", p.to_str().unwrap(), "--pixel", "2,2"]);
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.contains(&format!("f = 1, {want}, max_depth")),
            "{text}"
        );
    }
}

/// `hits -o x.csv` writes the table the grader reads: the same records as `-o x.json`,
/// row-major, and graded against its own scene it passes with no failing pixel.
#[test]
fn hits_writes_csv_that_reads_back_as_the_json_and_grades_clean() {
    use raytile::grade::{Hint, Submission};
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (24, 16);
    let scene = resized_scene(&dir, "showcase.json", w, h);
    let write = |name: &str, extra: &[&str]| {
        let p = dir.path().join(name);
        let mut args = vec!["hits", scene.to_str().unwrap(), "-o", p.to_str().unwrap()];
        args.extend_from_slice(extra);
        let out = run(&args);
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        std::fs::read(p).unwrap()
    };
    let json = write("h.json", &[]);
    let csv = write("h.csv", &["--tile", "7"]);
    assert_eq!(write("h.txt", &["--format", "csv"]), csv);
    let text = std::str::from_utf8(&csv).unwrap();
    assert!(
        text.starts_with("u,v,hit,object,lambda,px,py,pz,nx,ny,nz\n"),
        "{text}"
    );
    assert_eq!(text.lines().count() as u32, 1 + w * h);
    assert!(text.lines().nth(1).unwrap().starts_with("0,0,"), "{text}");
    let records = |bytes: &[u8], hint| match Submission::parse(bytes, hint).unwrap() {
        Submission::Hits(d) => d.place(w, h).unwrap(),
        Submission::Image(_) => panic!("hit data expected"),
    };
    let from_json = records(&json, Hint::Json);
    assert!(from_json.iter().any(|p| p.hit) && from_json.iter().any(|p| !p.hit));
    assert_eq!(records(&csv, Hint::Auto), from_json);
    let out = run(&[
        "grade",
        scene.to_str().unwrap(),
        dir.path().join("h.csv").to_str().unwrap(),
    ]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(stdout_json(&out)["failing_pixels"], 0);
}

/// An output file that already exists is written over in place; what the command leaves
/// is exactly what it writes to a new file, whether the old file was longer or shorter,
/// in every format.
#[test]
fn writing_over_an_existing_file_leaves_the_bytes_of_a_new_one() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "showcase.json", 40, 30);
    let write = |cmd: &str, name: &str| {
        let p = dir.path().join(name);
        let out = run(&[cmd, scene.to_str().unwrap(), "-o", p.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        std::fs::read(p).unwrap()
    };
    for (cmd, ext) in [
        ("hits", "npy"),
        ("hits", "json"),
        ("hits", "csv"),
        ("render", "png"),
    ] {
        let fresh = write(cmd, &format!("fresh.{ext}"));
        for old in [fresh.len() * 3, fresh.len() / 2, 10] {
            let name = format!("old-{old}.{ext}");
            std::fs::write(dir.path().join(&name), vec![0xab; old]).unwrap();
            assert!(
                write(cmd, &name) == fresh,
                "{cmd} over {old} bytes differs from a new {ext}"
            );
        }
    }
}
