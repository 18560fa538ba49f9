//! Outputs that appear whole or not at all, even when the process is killed.
//!
//! Every file of one run is written into a staging directory with a fixed, recognisable name
//! inside its destination directory (`.scantex-<label>.tmp/`, so a rename never crosses a file
//! system), and moved into place file by file at the end. The staging directory is created, and
//! locked, before any work, which is also the check that the destination is writable. Then:
//!
//! - an error or a panic drops the [`Staged`] value, which removes the staging directory;
//! - SIGINT or SIGTERM: the binary's handler calls [`abort_all`], which removes every live
//!   staging directory (waiting for a commit in progress to finish first) before it exits;
//! - SIGKILL leaves the staging directory behind under its fixed name. The next run with the same
//!   label into the same directory removes it (or, if the kill came in the middle of the renames,
//!   finishes them from the list written before the first rename), so leftovers never pile up.
//!
//! Two runs writing the same target at the same time would mix their files: the second one
//! finds the staging directory locked and stops with an error before doing any work.

use crate::error::{Error, Result};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The file inside a staging directory that holds its lock.
const LOCK: &str = "lock";
/// The file inside a staging directory listing the files to move into place, written just
/// before the first rename: its presence means the staged set is complete.
const COMMIT: &str = "commit";

/// Staging directories alive in this process, for [`abort_all`]; `None` once aborted.
static LIVE: Mutex<Option<Vec<Live>>> = Mutex::new(Some(Vec::new()));

/// What [`abort_all`] removes for one destination: its staging directory, then the
/// destination's directories that this run created, if they are still empty.
#[derive(Clone, PartialEq)]
struct Live {
    tmp: PathBuf,
    created: Vec<PathBuf>,
}

impl Live {
    /// Removes the staging directory and, with `created`, the directories made for it.
    fn remove(&self, created: bool) {
        let _ = std::fs::remove_dir_all(&self.tmp);
        if created {
            // Deepest first; a directory something else was put into stays.
            for d in &self.created {
                let _ = std::fs::remove_dir(d);
            }
        }
    }
}

/// The staging directory's name for a label.
pub fn staging_name(label: &str) -> String {
    format!(".scantex-{label}.tmp")
}

/// One destination directory with its staging directory.
struct Dir {
    dest: PathBuf,
    live: Live,
    /// Held open for the lock; released when dropped (or when the process dies).
    _lock: File,
    /// File names in the order they were written, which is the order they are moved in.
    names: Vec<String>,
}

/// A group of output files written under staging names and moved into place together by
/// [`Staged::commit`]; dropped uncommitted, it leaves nothing behind.
pub struct Staged {
    label: String,
    dirs: Vec<Dir>,
    committed: bool,
}

impl Staged {
    /// Staging for outputs labelled `label` (a short, file-name-safe word such as `texture`
    /// or the output file's own name), with no directory prepared yet: the first file
    /// written into a directory prepares it.
    pub fn new(label: &str) -> Self {
        Staged {
            label: label.replace(['/', '\\'], "_"),
            dirs: Vec::new(),
            committed: false,
        }
    }

    /// Staging for outputs into each of `dirs` (created if missing), prepared now: a
    /// directory that cannot be written, or that another run is writing with the same
    /// label, is an error before any work is done.
    pub fn begin(label: &str, dirs: &[&Path]) -> Result<Self> {
        let mut s = Staged::new(label);
        for d in dirs {
            s.dir(d)?;
        }
        Ok(s)
    }

    /// The index of `dest` in `self.dirs`, preparing it if new.
    fn dir(&mut self, dest: &Path) -> Result<usize> {
        if let Some(i) = self.dirs.iter().position(|d| d.dest == dest) {
            return Ok(i);
        }
        // The directories this creates, deepest first, so that a run that fails or is
        // stopped can take them away again.
        let created: Vec<PathBuf> = dest
            .ancestors()
            .take_while(|a| !a.as_os_str().is_empty() && !a.exists())
            .map(Path::to_path_buf)
            .collect();
        // create_dir_all's own error for a file in the way ("File exists") does not say
        // which part is wrong.
        if let Some(f) = dest.ancestors().find(|a| a.exists() && !a.is_dir()) {
            let what = if f == dest {
                "is a file, not a directory: the output must be a directory"
            } else {
                "is a file, not a directory: it cannot hold the output directory"
            };
            return Err(Error::io(
                f,
                std::io::Error::new(std::io::ErrorKind::AlreadyExists, what),
            ));
        }
        std::fs::create_dir_all(dest).map_err(|e| Error::io(dest, e))?;
        let live = Live {
            tmp: dest.join(staging_name(&self.label)),
            created,
        };
        let lock = match prepare(&live.tmp, dest) {
            Ok(l) => l,
            Err(e) => {
                // Another run's staging must not be touched: only the directories made here.
                for d in &live.created {
                    let _ = std::fs::remove_dir(d);
                }
                return Err(e);
            }
        };
        match LIVE.lock() {
            Ok(mut l) => match l.as_mut() {
                Some(v) => v.push(live.clone()),
                None => {
                    live.remove(true);
                    return Err(interrupted(dest));
                }
            },
            Err(_) => return Err(interrupted(dest)),
        }
        self.dirs.push(Dir {
            dest: dest.to_path_buf(),
            live,
            _lock: lock,
            names: Vec::new(),
        });
        Ok(self.dirs.len() - 1)
    }

    /// Writes `bytes` to a staging name for `path`; nothing appears at `path` until
    /// [`Staged::commit`]. Writing the same path twice keeps the second.
    pub fn write(&mut self, path: &Path, bytes: &[u8]) -> Result<()> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .filter(|n| n != LOCK && n != COMMIT)
            .ok_or_else(|| {
                Error::io(
                    path,
                    std::io::Error::new(
                        std::io::ErrorKind::InvalidInput,
                        "not a file name that can be written",
                    ),
                )
            })?;
        let dest = dir_of(path).to_path_buf();
        let i = self.dir(&dest)?;
        let d = &mut self.dirs[i];
        std::fs::write(d.live.tmp.join(&name), bytes).map_err(|e| Error::io(path, e))?;
        d.names.retain(|n| n != &name);
        d.names.push(name);
        Ok(())
    }

    /// Moves every staged file into place, in the order written, and removes the staging
    /// directories. A SIGINT or SIGTERM that arrives meanwhile waits until this is done.
    pub fn commit(mut self) -> Result<()> {
        let live = LIVE.lock().map_err(|_| interrupted(Path::new(".")))?;
        if live.is_none() {
            return Err(interrupted(
                self.dirs.first().map_or(Path::new("."), |d| &d.dest),
            ));
        }
        for d in &self.dirs {
            let tmp = &d.live.tmp;
            let list = d.names.join("\n");
            std::fs::write(tmp.join(COMMIT), list).map_err(|e| Error::io(tmp, e))?;
            move_into_place(tmp, &d.dest, &d.names)?;
        }
        drop(live);
        // Drop removes the (now empty) staging directories and keeps the destinations.
        self.committed = true;
        Ok(())
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        let mut live = LIVE.lock().ok();
        // Deepest destinations first, so a created parent is empty when its turn comes.
        for d in self.dirs.iter().rev() {
            d.live.remove(!self.committed);
            if let Some(Some(v)) = live.as_mut().map(|l| l.as_mut()) {
                v.retain(|p| p != &d.live);
            }
        }
    }
}

fn interrupted(dest: &Path) -> Error {
    Error::io(
        dest,
        std::io::Error::new(
            std::io::ErrorKind::Interrupted,
            "interrupted: outputs not written",
        ),
    )
}

/// Renames `names` from `tmp` into `dest`, skipping those already moved (a roll-forward).
fn move_into_place(tmp: &Path, dest: &Path, names: &[String]) -> Result<()> {
    for n in names {
        let from = tmp.join(n);
        if from.exists() {
            std::fs::rename(&from, dest.join(n)).map_err(|e| Error::io(dest.join(n), e))?;
        }
    }
    Ok(())
}

/// Creates (or takes over) the staging directory `tmp` of `dest` and locks it. What a killed
/// run left there is removed, or, if it was killed while moving its files into place, moved on
/// into place first, so that `dest` holds one complete result.
fn prepare(tmp: &Path, dest: &Path) -> Result<File> {
    match std::fs::create_dir(tmp) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && tmp.is_dir() => {}
        Err(e) => return Err(Error::io(dest, e)),
    }
    let lock_path = tmp.join(LOCK);
    let lock = File::create(&lock_path).map_err(|e| Error::io(dest, e))?;
    match lock.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            return Err(Error::io(
                dest,
                std::io::Error::new(
                    std::io::ErrorKind::ResourceBusy,
                    format!(
                        "another scantex run is writing these outputs (it holds {}); wait for it or choose another output",
                        tmp.display()
                    ),
                ),
            ))
        }
        // File systems without locks (some network mounts): go on unlocked.
        Err(std::fs::TryLockError::Error(_)) => {}
    }
    let commit = tmp.join(COMMIT);
    if let Ok(list) = std::fs::read_to_string(&commit) {
        let names: Vec<String> = list.lines().map(str::to_string).collect();
        move_into_place(tmp, dest, &names)?;
    }
    let entries = std::fs::read_dir(tmp).map_err(|e| Error::io(tmp, e))?;
    for e in entries.flatten() {
        if e.file_name() != LOCK {
            let p = e.path();
            let r = if p.is_dir() {
                std::fs::remove_dir_all(&p)
            } else {
                std::fs::remove_file(&p)
            };
            r.map_err(|e| Error::io(&p, e))?;
        }
    }
    Ok(lock)
}

/// Removes every live staging directory and refuses new ones and commits from then on: for a
/// signal handler that is about to end the process. Waits for a commit in progress.
pub fn abort_all() {
    let mut live = match LIVE.lock() {
        Ok(l) => l,
        Err(p) => p.into_inner(),
    };
    if let Some(dirs) = live.take() {
        for d in dirs.iter().rev() {
            d.remove(true);
        }
    }
}

/// The directory a file is written into: its parent, or `.` for a bare file name.
pub fn dir_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The staging label of a single-file output: its file name.
pub fn label_of(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into())
}

/// Writes `bytes` to `path` through a staging directory and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut s = Staged::new(&label_of(path));
    s.write(path, bytes)?;
    s.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn listing(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn committed_files_appear_together_and_the_staging_directory_goes() {
        let d = tempfile::tempdir().unwrap();
        let mut s = Staged::begin("t", &[d.path()]).unwrap();
        assert_eq!(listing(d.path()), vec![".scantex-t.tmp"]);
        s.write(&d.path().join("a.txt"), b"a").unwrap();
        s.write(&d.path().join("b.txt"), b"b").unwrap();
        assert!(!d.path().join("a.txt").exists());
        s.commit().unwrap();
        assert_eq!(listing(d.path()), vec!["a.txt", "b.txt"]);
        assert_eq!(std::fs::read(d.path().join("b.txt")).unwrap(), b"b");
    }

    #[test]
    fn a_dropped_staging_leaves_nothing() {
        let d = tempfile::tempdir().unwrap();
        let mut s = Staged::begin("t", &[d.path()]).unwrap();
        s.write(&d.path().join("a.txt"), b"a").unwrap();
        drop(s);
        assert!(listing(d.path()).is_empty());
    }

    #[test]
    fn directories_made_for_a_run_that_fails_are_taken_away() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("a").join("b");
        let s = Staged::begin("t", &[&out]).unwrap();
        assert!(out.is_dir());
        drop(s);
        assert!(listing(d.path()).is_empty());
        let mut s = Staged::begin("t", &[&out]).unwrap();
        s.write(&out.join("x.txt"), b"x").unwrap();
        s.commit().unwrap();
        assert_eq!(listing(&out), vec!["x.txt"]);
    }

    #[test]
    fn a_second_writer_of_the_same_target_is_refused_until_the_first_is_done() {
        let d = tempfile::tempdir().unwrap();
        let s = Staged::begin("t", &[d.path()]).unwrap();
        let err = Staged::begin("t", &[d.path()]).err().unwrap().to_string();
        assert!(err.contains("another scantex run"), "{err}");
        // Another label is another target.
        Staged::begin("u", &[d.path()]).unwrap();
        drop(s);
        Staged::begin("t", &[d.path()]).unwrap();
    }

    #[test]
    fn leftovers_of_a_killed_run_are_removed_or_rolled_forward() {
        let d = tempfile::tempdir().unwrap();
        // Killed while writing: the staged files are junk.
        let tmp = d.path().join(staging_name("t"));
        std::fs::create_dir(&tmp).unwrap();
        std::fs::write(tmp.join("a.txt"), b"half").unwrap();
        let s = Staged::begin("t", &[d.path()]).unwrap();
        drop(s);
        assert!(listing(d.path()).is_empty());
        // Killed between two renames: the rest is moved into place.
        std::fs::create_dir(&tmp).unwrap();
        std::fs::write(d.path().join("a.txt"), b"new a").unwrap();
        std::fs::write(tmp.join("b.txt"), b"new b").unwrap();
        std::fs::write(tmp.join(COMMIT), "a.txt\nb.txt").unwrap();
        drop(Staged::begin("t", &[d.path()]).unwrap());
        assert_eq!(listing(d.path()), vec!["a.txt", "b.txt"]);
        assert_eq!(std::fs::read(d.path().join("b.txt")).unwrap(), b"new b");
    }

    #[test]
    fn an_unwritable_destination_fails_before_any_work() {
        let d = tempfile::tempdir().unwrap();
        let file = d.path().join("plain");
        std::fs::write(&file, b"x").unwrap();
        let err = Staged::begin("t", &[&file.join("sub")]).err().unwrap();
        assert!(err.to_string().contains("plain"), "{err}");
    }
}
