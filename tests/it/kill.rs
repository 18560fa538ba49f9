//! A run stopped as a batch scheduler stops it (SIGTERM at its time limit, SIGKILL after the
//! grace period) never leaves a half-written or mixed result: the output directory holds the
//! previous complete result or the new complete one, SIGTERM leaves no staging files, and the
//! next run cleans up what a SIGKILL left.
#![cfg(unix)]

use crate::common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A file's content as compared here: its bytes, except `report.json`, whose timings and
/// memory figures differ from run to run, so those are taken out.
#[derive(PartialEq)]
enum Content {
    Bytes(Vec<u8>),
    Report(serde_json::Value),
    Dir,
}

impl std::fmt::Debug for Content {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Content::Bytes(b) => write!(f, "{} bytes", b.len()),
            Content::Report(_) => write!(f, "report"),
            Content::Dir => write!(f, "directory"),
        }
    }
}

/// Removes every member whose name speaks of time or memory.
fn without_timings(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(m) => {
            m.retain(|k, _| !(k.contains("seconds") || k.contains("peak")));
            m.values_mut().for_each(without_timings);
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(without_timings),
        _ => {}
    }
}

/// Every entry of `dir` (names, staging directory included) with its content.
fn snapshot(dir: &Path) -> BTreeMap<String, Content> {
    let mut out = BTreeMap::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries {
            let e = e.unwrap();
            let name = e.file_name().to_string_lossy().into_owned();
            let content = if !e.path().is_file() {
                Content::Dir
            } else if name == "report.json" {
                let mut v: serde_json::Value =
                    serde_json::from_slice(&std::fs::read(e.path()).unwrap())
                        .expect("report.json is whole");
                without_timings(&mut v);
                Content::Report(v)
            } else {
                Content::Bytes(std::fs::read(e.path()).unwrap())
            };
            out.insert(name, content);
        }
    }
    out
}

fn texture(out: &Path, seed: &str) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_scantex"));
    c.args(["texture", "-q", "--size", "512", "--seed", seed])
        .arg(common::root().join("samples/torus"))
        .arg("-o")
        .arg(out)
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    c
}

fn run(out: &Path, seed: &str) -> Duration {
    let t = Instant::now();
    let status = texture(out, seed).status().unwrap();
    assert!(status.success());
    t.elapsed()
}

#[test]
fn killed_runs_leave_a_complete_result_and_nothing_else() {
    let root = tempfile::tempdir().unwrap();
    let (old_dir, new_dir, work) = (
        root.path().join("old"),
        root.path().join("new"),
        root.path().join("work"),
    );
    // The two complete results a killed run may leave: the previous one (seed 1) and the
    // new one (seed 2; restoration's random choices differ, so the atlases do too).
    let took = run(&old_dir, "1");
    run(&new_dir, "2");
    let old = snapshot(&old_dir);
    let new = snapshot(&new_dir);
    assert_eq!(
        old.keys().collect::<Vec<_>>(),
        [
            "model.glb",
            "model.mtl",
            "model.obj",
            "model.png",
            "report.json"
        ]
    );
    assert!(old["model.png"] != new["model.png"]);
    let names: Vec<&String> = old.keys().collect();
    let mut signals = 0;
    for (signal, fraction) in [
        (libc_sig::TERM, 0.05),
        (libc_sig::TERM, 0.5),
        (libc_sig::TERM, 0.95),
        (libc_sig::KILL, 0.05),
        (libc_sig::KILL, 0.5),
        (libc_sig::KILL, 0.95),
    ] {
        std::fs::remove_dir_all(&work).ok();
        common::copy_dir(&old_dir, &work);
        let mut child = texture(&work, "2").spawn().unwrap();
        std::thread::sleep(took.mul_f64(fraction));
        let sent = Command::new("kill")
            .arg(format!("-{signal}"))
            .arg(child.id().to_string())
            .status()
            .unwrap()
            .success();
        let status = child.wait().unwrap();
        if !sent || status.success() {
            // The run finished first: the new result must be there whole.
            assert!(
                snapshot(&work) == new,
                "{signal} at {fraction}: not the new result"
            );
            continue;
        }
        signals += 1;
        let left = snapshot(&work);
        let staging = left.keys().filter(|k| k.starts_with(".scantex-")).count();
        if signal == libc_sig::TERM {
            // SIGTERM: exit status 128 + 15 and the staging directory removed.
            assert_eq!(status.code(), Some(143));
            assert_eq!(staging, 0, "{:?}", left.keys());
        }
        let files: BTreeMap<&String, &Content> = left
            .iter()
            .filter(|(k, _)| !k.starts_with(".scantex-"))
            .collect();
        assert_eq!(files.keys().copied().collect::<Vec<_>>(), names);
        let same = |r: &BTreeMap<String, Content>| files.iter().all(|(k, v)| r[*k] == **v);
        assert!(
            same(&old) || same(&new),
            "{signal} at {fraction}: a mix of the old and new result"
        );
        // The next run completes and leaves only its result.
        run(&work, "2");
        assert!(
            snapshot(&work) == new,
            "after {signal} at {fraction}: {:?}",
            snapshot(&work).keys()
        );
    }
    assert!(
        signals >= 4,
        "only {signals} of 6 runs were stopped by the signal"
    );
}

/// Signal names for `kill -<name>`.
mod libc_sig {
    pub const TERM: &str = "TERM";
    pub const KILL: &str = "KILL";
}
