//! Output folders are claimed, not checked. A command that writes a
//! folder claims `--out` before its work starts ([`Claim::new`]): what is
//! there is looked at once (nothing; or, with `--force`, a folder of the
//! same kind that coid wrote, whose state is remembered), and a staging
//! folder is made beside it (`.<name>.tmp-<pid>-XXXXXX`). The work fills
//! the staging folder; [`Claim::publish`] writes the folder's identity
//! (`.coid-folder.toml`: its kind and every file it holds) and renames it
//! into place with a rename that never replaces what it did not expect:
//!
//! - nothing was there: an atomic rename that fails if anything appeared
//!   meanwhile (Linux `RENAME_NOREPLACE`);
//! - a folder was to be replaced (`--force`): it is moved aside, compared
//!   with its state at the claim, and only then removed; a folder that
//!   changed meanwhile is put back.
//!
//! When the rename is refused, the new results are not lost: they are
//! renamed to `<name>.coid-<pid>` beside `--out` and the error says so.
//!
//! Staging folders of processes that are gone (killed outright) are
//! removed when any folder is next claimed in the same parent; while a
//! live coid fills a staging folder for the same `--out`, a second claim
//! is refused. Folders that grow over several commands (a batch, a models
//! folder, a family of scenarios) are identified per kind instead
//! ([`ResultKind::check`]).

use std::path::{Path, PathBuf};

use super::identity::{IDENTITY, ResultKind, check_whole, files_in, read_identity};
use super::records::{BatchRun, FolderRecord};
use super::staging::{keep_beside, other_writer, rename_noreplace, staging_dir};
use super::{OutputError, io};

/// What to do when an output folder exists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Existing {
    /// Refuse (no `--force`).
    Refuse,
    /// Replace it if it is a folder of the same kind that coid wrote and
    /// that holds what coid wrote there (`--force`).
    Replace,
    /// Replace any run folder coid wrote, whole or damaged (a batch's
    /// worker, for a run the batch found incomplete).
    Rerun,
}

impl Existing {
    /// `Replace` with `--force`, else `Refuse`.
    pub fn when(force: bool) -> Self {
        if force {
            Existing::Replace
        } else {
            Existing::Refuse
        }
    }
}

/// `Ok` when `out` may be written by a command of `kind` without being
/// claimed (folders that grow: a models folder, a family of scenarios):
/// it does not exist, or it is a folder of that kind and `existing` allows
/// adding to it.
pub fn check_extendable(
    out: &Path,
    kind: ResultKind,
    existing: Existing,
) -> Result<(), OutputError> {
    match what_is_at(out)? {
        None => Ok(()),
        Some(()) if existing == Existing::Refuse => Err(OutputError::Exists(out.to_owned())),
        Some(()) => kind.check(out).map_err(|why| OutputError::NotExtendable {
            path: out.to_owned(),
            kind: kind.label(),
            why,
        }),
    }
}

/// `Some` when a folder is at `out`, `None` when nothing is; an error when
/// a file or a symbolic link is (never followed or replaced).
fn what_is_at(out: &Path) -> Result<Option<()>, OutputError> {
    let not_a_folder = |what: String| OutputError::NotAFolder {
        path: out.to_owned(),
        what,
    };
    if out.file_name().is_none() {
        return Err(not_a_folder("not a folder name".into()));
    }
    match std::fs::symlink_metadata(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(io(out)(e)),
        Ok(m) if m.file_type().is_symlink() => {
            let to = std::fs::read_link(out)
                .map(|t| t.display().to_string())
                .unwrap_or_default();
            let what = if out.exists() {
                format!("a symbolic link (to {to})")
            } else {
                format!("a symbolic link to {to}, which does not exist")
            };
            Err(not_a_folder(what))
        }
        Ok(m) if !m.is_dir() => Err(not_a_folder("a file".into())),
        Ok(_) => Ok(Some(())),
    }
}

/// The state of a folder at its claim, compared before it is replaced:
/// every entry under it with its size and modification time.
#[derive(Debug, PartialEq)]
struct Fingerprint(Vec<(String, u64, Option<std::time::SystemTime>)>);

fn fingerprint(dir: &Path) -> std::io::Result<Fingerprint> {
    fn walk(
        dir: &Path,
        prefix: &str,
        out: &mut Vec<(String, u64, Option<std::time::SystemTime>)>,
    ) -> std::io::Result<()> {
        for e in std::fs::read_dir(dir)? {
            let e = e?;
            let meta = std::fs::symlink_metadata(e.path())?;
            let name = format!("{prefix}{}", e.file_name().to_string_lossy());
            out.push((name.clone(), meta.len(), meta.modified().ok()));
            if meta.is_dir() {
                walk(&e.path(), &format!("{name}/"), out)?;
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(dir, "", &mut out)?;
    out.sort();
    Ok(Fingerprint(out))
}

/// An output folder claimed by this process: filled in [`Claim::dir`],
/// then published with [`Claim::publish`]. Dropped unpublished (an error,
/// a panic), it leaves nothing behind and `out` untouched; on SIGINT or
/// SIGTERM the staging folder is removed too (`crate::interrupt`).
pub struct Claim {
    out: PathBuf,
    parent: PathBuf,
    name: String,
    kind: ResultKind,
    /// The state of the folder `--force` is to replace, if one was there.
    found: Option<Fingerprint>,
    batch_run: Option<BatchRun>,
    _registered: crate::interrupt::Registered,
    staging: tempfile::TempDir,
}

impl Claim {
    /// Claims `out` for a command that writes a folder of `kind`: refused
    /// at once when something is there that `existing` does not allow,
    /// when another coid is filling the same folder now, or when its
    /// parent cannot be written.
    pub fn new(out: &Path, kind: ResultKind, existing: Existing) -> Result<Claim, OutputError> {
        let found = match what_is_at(out)? {
            None => None,
            Some(()) => {
                let allowed = match existing {
                    Existing::Refuse => return Err(OutputError::Exists(out.to_owned())),
                    Existing::Replace => kind.check(out),
                    Existing::Rerun => read_identity(out).and_then(|r| {
                        (r.kind == kind.name())
                            .then_some(())
                            .ok_or_else(|| "it is not a run folder".to_owned())
                    }),
                };
                allowed.map_err(|why| OutputError::NotReplaceable {
                    path: out.to_owned(),
                    kind: kind.label(),
                    why,
                })?;
                Some(fingerprint(out).map_err(io(out))?)
            }
        };
        let parent = match out.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).map_err(io(&parent))?;
        let name = out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        // Registered as it is made: Ctrl-C from here on removes it.
        let (staging, registered) =
            crate::interrupt::make_registered(|| staging_dir(&parent, &name))?;
        if let Some(pid) = other_writer(&parent, &name, staging.path()) {
            return Err(OutputError::Busy {
                path: out.to_owned(),
                pid,
            });
        }
        Ok(Claim {
            out: out.to_owned(),
            parent,
            name,
            kind,
            found,
            batch_run: None,
            _registered: registered,
            staging,
        })
    }

    /// Marks the folder as run `batch_run.run` of a batch (its identity
    /// says so).
    pub fn of_batch_run(mut self, batch_run: BatchRun) -> Self {
        self.batch_run = Some(batch_run);
        self
    }

    /// Where to write the folder's files.
    pub fn dir(&self) -> &Path {
        self.staging.path()
    }

    /// The folder's final place.
    pub fn out(&self) -> &Path {
        &self.out
    }

    /// Fills the folder with `fill`, then publishes it.
    pub fn fill<E: From<OutputError>>(
        self,
        fill: impl FnOnce(&Path) -> Result<(), E>,
    ) -> Result<(), E> {
        fill(self.dir())?;
        self.publish()?;
        Ok(())
    }

    /// Writes the identity and renames the complete folder into place (see
    /// the module documentation); when that is refused, keeps it beside
    /// `out` and says where.
    pub fn publish(self) -> Result<(), OutputError> {
        let record = FolderRecord {
            kind: self.kind.name().to_owned(),
            coid_version: env!("CARGO_PKG_VERSION").to_owned(),
            batch_run: self.batch_run.clone(),
            files: files_in(self.dir()).map_err(io(self.dir()))?,
        };
        let text = record.to_toml().map_err(OutputError::Batch)?;
        let identity = self.dir().join(IDENTITY);
        std::fs::write(&identity, text).map_err(io(&identity))?;
        let Claim {
            out,
            parent,
            name,
            found,
            _registered,
            staging,
            ..
        } = self;
        let staged = staging.path().to_owned();
        let Some(before) = found else {
            return match rename_noreplace(&staged, &out) {
                Ok(()) => {
                    let _ = staging.keep();
                    Ok(())
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let kept = keep_beside(staging, &parent, &name)?;
                    Err(OutputError::Appeared { path: out, kept })
                }
                Err(e) => Err(io(&out)(e)),
            };
        };
        // Move the old folder aside, then make sure it is what was claimed.
        let aside = staging_dir(&parent, &format!("{name}.old"))?;
        let old = aside.path().join("old");
        std::fs::rename(&out, &old).map_err(io(&out))?;
        if fingerprint(&old).ok().as_ref() != Some(&before) {
            let back = rename_noreplace(&old, &out);
            if back.is_ok() {
                drop(aside);
            } else {
                let _ = keep_beside(aside, &parent, &format!("{name}.old"));
            }
            let kept = keep_beside(staging, &parent, &name)?;
            return Err(OutputError::Changed { path: out, kept });
        }
        match rename_noreplace(&staged, &out) {
            Ok(()) => {
                let _ = staging.keep();
                drop(aside);
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let _ = keep_beside(aside, &parent, &format!("{name}.old"));
                let kept = keep_beside(staging, &parent, &name)?;
                Err(OutputError::Appeared { path: out, kept })
            }
            Err(e) => Err(io(&out)(e)),
        }
    }
}

/// Adds files (or folders) to the existing folder `dir`: `fill` writes
/// them into a temporary folder inside `dir`, then each is renamed into
/// place in name order (an existing file or folder of the same name is
/// replaced: a folder is moved aside first and removed with the temporary
/// folder). Interrupted before the renames, `dir` is as it was.
pub fn publish_files<E: From<OutputError>>(
    dir: &Path,
    fill: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let (staged, _registered) = crate::interrupt::make_registered(|| staging_dir(dir, "staging"))?;
    fill(staged.path())?;
    let mut names: Vec<_> = std::fs::read_dir(staged.path())
        .map_err(io(staged.path()))?
        .map(|e| e.map(|e| e.file_name()))
        .collect::<Result<_, _>>()
        .map_err(io(staged.path()))?;
    names.sort();
    let aside = staged.path().join(".replaced");
    for name in names {
        let dst = dir.join(&name);
        if std::fs::symlink_metadata(&dst).is_ok_and(|m| m.is_dir()) {
            std::fs::create_dir_all(&aside).map_err(io(&aside))?;
            std::fs::rename(&dst, aside.join(&name)).map_err(io(&dst))?;
        }
        std::fs::rename(staged.path().join(&name), &dst).map_err(io(&dst))?;
    }
    Ok(())
}

/// Whether `dir` is run `expected.run` of the batch `expected` names, whole:
/// its identity says so and it holds exactly the files it lists.
pub fn is_batch_run(dir: &Path, expected: &BatchRun) -> bool {
    check_whole(dir, ResultKind::Run).is_ok_and(|r| r.batch_run.as_ref() == Some(expected))
}

/// Copies a folder coid wrote (its files and its identity) into `dst`,
/// which must not exist.
pub fn copy_folder(src: &Path, dst: &Path) -> Result<(), OutputError> {
    std::fs::create_dir_all(dst).map_err(io(dst))?;
    for e in std::fs::read_dir(src).map_err(io(src))? {
        let p = e.map_err(io(src))?.path();
        let to = dst.join(p.file_name().unwrap_or_default());
        if p.is_dir() {
            copy_folder(&p, &to)?;
        } else {
            std::fs::copy(&p, &to).map_err(io(&to))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    fn write(dir: &Path, name: &str, text: &str) -> Result<(), OutputError> {
        let p = dir.join(name);
        std::fs::write(&p, text).map_err(io(&p))
    }

    #[test]
    fn a_folder_appears_complete_or_not_at_all() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("res");
        let claim = |e| Claim::new(&out, ResultKind::Eval, e);
        // A failing fill leaves nothing behind.
        let e = claim(Existing::Refuse).unwrap().fill(|d| {
            write(d, "a.csv", "half")?;
            Err(OutputError::Batch("boom".into()))
        });
        assert!(e.is_err());
        assert!(names(root.path()).is_empty(), "{:?}", names(root.path()));
        // A complete one appears, with its identity; an existing one is
        // kept without force...
        claim(Existing::Refuse)
            .unwrap()
            .fill(|d| write(d, "a.csv", "one"))
            .unwrap();
        assert_eq!(names(&out), vec![IDENTITY, "a.csv"]);
        assert!(matches!(
            claim(Existing::Refuse).map(drop),
            Err(OutputError::Exists(_))
        ));
        // ...and replaced with force, only once the new one is complete.
        let e = claim(Existing::Replace)
            .unwrap()
            .fill(|_| Err(OutputError::Batch("no".into())));
        assert!(e.is_err());
        assert_eq!(std::fs::read_to_string(out.join("a.csv")).unwrap(), "one");
        claim(Existing::Replace)
            .unwrap()
            .fill(|d| write(d, "b.csv", "two"))
            .unwrap();
        assert_eq!(names(&out), vec![IDENTITY, "b.csv"]);
        assert_eq!(names(root.path()), vec!["res"]);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&out).unwrap().permissions().mode();
            assert_ne!(
                mode & 0o055,
                0,
                "a results folder is readable by others: {mode:o}"
            );
        }
    }

    /// What appears at `out` while a command runs is never replaced: the
    /// new results are kept beside it; a folder `--force` was to replace
    /// that changed meanwhile is put back.
    #[test]
    fn a_claimed_folder_never_replaces_what_appeared_or_changed() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("res");
        let c = Claim::new(&out, ResultKind::Run, Existing::Refuse).unwrap();
        write(c.dir(), "summary.csv", "mine").unwrap();
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("theirs.txt"), "precious").unwrap();
        let e = c.publish().unwrap_err().to_string();
        assert!(e.contains("appeared while"), "{e}");
        assert_eq!(names(&out), vec!["theirs.txt"]);
        let kept = root.path().join(format!("res.coid-{}", std::process::id()));
        assert_eq!(
            std::fs::read_to_string(kept.join("summary.csv")).unwrap(),
            "mine"
        );
        std::fs::remove_dir_all(&kept).unwrap();
        // --force on a run folder coid wrote; a file added meanwhile.
        std::fs::remove_dir_all(&out).unwrap();
        Claim::new(&out, ResultKind::Run, Existing::Refuse)
            .unwrap()
            .fill(|d| write(d, "summary.csv", "old"))
            .unwrap();
        let c = Claim::new(&out, ResultKind::Run, Existing::Replace).unwrap();
        std::fs::write(out.join("note.txt"), "added").unwrap();
        let e = c.publish().unwrap_err().to_string();
        assert!(e.contains("changed while"), "{e}");
        assert_eq!(
            std::fs::read_to_string(out.join("note.txt")).unwrap(),
            "added"
        );
        assert!(kept.is_dir());
    }

    #[test]
    fn force_needs_an_identity_of_the_same_kind_and_unchanged_files() {
        let root = tempfile::tempdir().unwrap();
        let out = root.path().join("res");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("summary.csv"), "mine").unwrap();
        let why = |kind| match Claim::new(&out, kind, Existing::Replace) {
            Err(e) => e.to_string(),
            Ok(_) => "accepted".into(),
        };
        assert!(why(ResultKind::Run).contains("no .coid-folder.toml"));
        std::fs::remove_dir_all(&out).unwrap();
        Claim::new(&out, ResultKind::Run, Existing::Refuse)
            .unwrap()
            .fill(|d| write(d, "summary.csv", "x"))
            .unwrap();
        assert!(why(ResultKind::Eval).contains("it holds a run's results"));
        assert_eq!(why(ResultKind::Run), "accepted");
        std::fs::write(out.join("summary.csv"), "longer").unwrap();
        assert!(why(ResultKind::Run).contains("summary.csv changed"));
        std::fs::write(out.join("summary.csv"), "x").unwrap();
        std::fs::write(out.join("c.toml"), "").unwrap();
        assert!(why(ResultKind::Run).contains("it holds c.toml"));
    }

    /// Staging folders left by processes that are gone (killed) are
    /// removed when any folder is claimed in the same parent; a live
    /// process's staging folder for the same name refuses the claim.
    #[test]
    fn stale_staging_folders_of_dead_processes_are_removed() {
        let root = tempfile::tempdir().unwrap();
        // Above Linux's pid_max: no such process.
        let dead = root.path().join(".other.tmp-2147483000-abc123");
        std::fs::create_dir_all(&dead).unwrap();
        let out = root.path().join("res");
        Claim::new(&out, ResultKind::Eval, Existing::Refuse)
            .unwrap()
            .fill(|d| write(d, "a.csv", "x"))
            .unwrap();
        assert!(!dead.exists());
        // pid 1 always runs.
        let live = root.path().join(".next.tmp-1-def456");
        std::fs::create_dir_all(&live).unwrap();
        let e = Claim::new(
            &root.path().join("next"),
            ResultKind::Eval,
            Existing::Refuse,
        )
        .map(drop)
        .unwrap_err()
        .to_string();
        assert!(e.contains("pid 1"), "{e}");
        assert!(live.exists());
    }

    #[test]
    fn published_files_replace_old_ones_and_leave_no_staging() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "summary.csv", "old").unwrap();
        publish_files(dir.path(), |t| {
            write(t, "summary.csv", "new")?;
            write(t, "summary.md", "md")
        })
        .unwrap();
        assert_eq!(names(dir.path()), vec!["summary.csv", "summary.md"]);
        assert_eq!(
            std::fs::read_to_string(dir.path().join("summary.csv")).unwrap(),
            "new"
        );
        assert!(publish_files(dir.path(), |_| Err(OutputError::Batch("x".into()))).is_err());
        assert_eq!(names(dir.path()), vec!["summary.csv", "summary.md"]);
    }
}
