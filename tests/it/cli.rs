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

/// Between two facing mirrors every ray recurses to `max_depth`, a level of the tracer's
/// stack each bounce. At the deepest `max_depth` the renderer takes, `render`, `hits`
/// and `trace` finish (an overflow would abort the process); one deeper is refused as
/// an invalid scene, with its JSON pointer, though the command line sets no limits.
#[test]
fn facing_mirrors_at_the_deepest_max_depth_finish_and_one_deeper_is_refused() {
    use raytile::scene::DEEPEST;
    let dir = tempfile::tempdir().unwrap();
    let deepest = scene_file(&dir, "deepest.json", &facing_mirrors(DEEPEST));
    let deepest = deepest.to_str().unwrap();
    let png = dir.path().join("deepest.png");
    let npy = dir.path().join("deepest.npy");
    for args in [
        vec!["render", deepest, "-o", png.to_str().unwrap()],
        vec!["hits", deepest, "-o", npy.to_str().unwrap()],
        vec!["trace", deepest, "--pixel", "1,1", "--format", "json"],
    ] {
        let out = run(&args);
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let (w, h, _) = decode_png(&std::fs::read(&png).unwrap());
    assert_eq!((w, h), (8, 8));
    // The explanation follows the pixel's ray down the bounces.
    let out = run(&["trace", deepest, "--pixel", "1,1"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("reflected ray, depth 40:"), "{text}");

    let deeper = scene_file(&dir, "deeper.json", &facing_mirrors(DEEPEST + 1));
    let (png, npy) = (dir.path().join("deeper.png"), dir.path().join("deeper.npy"));
    for (command, more) in [
        ("render", ["-o", png.to_str().unwrap()]),
        ("hits", ["-o", npy.to_str().unwrap()]),
        ("trace", ["--pixel", "1,1"]),
    ] {
        let mut args = vec![command, deeper.to_str().unwrap()];
        args.extend(more);
        let out = run(&args);
        assert!(!out.status.success(), "{command}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(&format!(
                "/max_depth: {} is more than the limit of {DEEPEST}",
                DEEPEST + 1
            )),
            "{command}: {err}"
        );
    }
}
