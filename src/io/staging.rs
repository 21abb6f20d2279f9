//! Staging folders: where a folder is filled before it is published
//! (`.<name>.tmp-<pid>-XXXXXX` beside it, a shortened name for names near
//! the file system's limit), the removal of those whose process is gone,
//! a live claim by another process, and the rename that never replaces.

use std::path::{Path, PathBuf};

use super::{OutputError, io};

/// Renames a staging folder to `<name>.coid-<pid>` (or `-2`, `-3`, ...)
/// beside the folder it was for, so that it is kept, and returns that
/// path.
pub(super) fn keep_beside(
    staging: tempfile::TempDir,
    parent: &Path,
    name: &str,
) -> Result<PathBuf, OutputError> {
    let from = staging.path().to_owned();
    let pid = std::process::id();
    for k in 1..100 {
        let to = parent.join(if k == 1 {
            format!("{name}.coid-{pid}")
        } else {
            format!("{name}.coid-{pid}-{k}")
        });
        if rename_noreplace(&from, &to).is_ok() {
            let _ = staging.keep();
            return Ok(to);
        }
    }
    Err(io(&from)(std::io::Error::other(
        "cannot rename the results beside their folder",
    )))
}

/// Renames `from` to `to`, failing with `AlreadyExists` when anything is at
/// `to`, atomically where the file system can (Linux `renameat2` with
/// `RENAME_NOREPLACE`), else by a check just before the rename.
pub(super) fn rename_noreplace(from: &Path, to: &Path) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::ffi::OsStrExt;
        let c = |p: &Path| {
            std::ffi::CString::new(p.as_os_str().as_bytes())
                .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))
        };
        let (f, t) = (c(from)?, c(to)?);
        // SAFETY: two NUL-terminated paths relative to the working folder.
        let r = unsafe {
            libc::renameat2(
                libc::AT_FDCWD,
                f.as_ptr(),
                libc::AT_FDCWD,
                t.as_ptr(),
                libc::RENAME_NOREPLACE,
            )
        };
        if r == 0 {
            return Ok(());
        }
        let e = std::io::Error::last_os_error();
        match e.raw_os_error() {
            Some(libc::EEXIST) | Some(libc::ENOTEMPTY) => {
                return Err(std::io::ErrorKind::AlreadyExists.into());
            }
            // The file system cannot: fall back below.
            Some(libc::EINVAL) | Some(libc::ENOSYS) => {}
            _ => return Err(e),
        }
    }
    if std::fs::symlink_metadata(to).is_ok() {
        return Err(std::io::ErrorKind::AlreadyExists.into());
    }
    std::fs::rename(from, to)
}

/// The part of a staging folder's name that stands for `name`: `name`
/// itself, or, for names so long that the staging name would pass the
/// file system's 255 bytes, its first 150 bytes and a hash of the rest.
fn stem_of(name: &str) -> String {
    if name.len() <= 200 {
        return name.to_owned();
    }
    let mut cut = 150;
    while !name.is_char_boundary(cut) {
        cut -= 1;
    }
    format!(
        "{}~{}",
        &name[..cut],
        &super::records::fnv64_hex(name.as_bytes())[..8]
    )
}

/// A temporary folder in `parent` named `.<name>.tmp-<pid>-XXXXXX`, with
/// the permissions a plain `mkdir` would give (tempfile's default is
/// 0700). Staging folders left in `parent` by processes that no longer
/// run (killed, out of memory) are removed first, whatever folder they
/// were for.
pub(crate) fn staging_dir(parent: &Path, name: &str) -> Result<tempfile::TempDir, OutputError> {
    remove_stale_staging(parent);
    let prefix = format!(".{}.tmp-{}-", stem_of(name), std::process::id());
    let mut b = tempfile::Builder::new();
    b.prefix(&prefix);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o777));
    }
    b.tempdir_in(parent).map_err(io(parent))
}

/// The pid in a staging folder's name (`.<stem>.tmp-<pid>-XXXXXX`), if it
/// is one.
fn staging_pid(name: &str) -> Option<(&str, i32)> {
    let rest = name.strip_prefix('.')?;
    let k = rest.rfind(".tmp-")?;
    let (stem, tail) = (&rest[..k], &rest[k + 5..]);
    let (pid, random) = tail.split_once('-')?;
    let random_ok = random.len() == 6 && random.chars().all(|c| c.is_ascii_alphanumeric());
    let pid = pid.parse::<i32>().ok()?;
    random_ok.then_some((stem, pid))
}

pub(super) fn is_staging_name(name: &str) -> bool {
    staging_pid(name).is_some()
}

/// Removes the staging folders in `parent` whose process is gone (best
/// effort: one that cannot be removed stays).
fn remove_stale_staging(parent: &Path) {
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    for e in entries.flatten() {
        let file_name = e.file_name();
        let Some((_, pid)) = file_name.to_str().and_then(staging_pid) else {
            continue;
        };
        if !crate::interrupt::process_runs(pid) && e.path().is_dir() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// Another live process that claimed `name` in `parent` before this one
/// (its staging folder `mine` made earlier, or at the same time by a
/// smaller pid): its pid. Of two claims at once, exactly one goes on.
pub(super) fn other_writer(parent: &Path, name: &str, mine: &Path) -> Option<u32> {
    let stem = stem_of(name);
    let me = std::process::id() as i32;
    let made = |p: &Path| std::fs::metadata(p).and_then(|m| m.created()).ok();
    let my_time = made(mine);
    std::fs::read_dir(parent)
        .ok()?
        .flatten()
        .filter_map(|e| {
            let n = e.file_name().to_str()?.to_owned();
            let (s, pid) = staging_pid(&n)?;
            let first = (made(&e.path()), pid) < (my_time, me);
            (s == stem && pid != me && first && crate::interrupt::process_runs(pid))
                .then_some(pid as u32)
        })
        .next()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_names_get_a_short_staging_name() {
        let long = "x".repeat(250);
        let stem = stem_of(&long);
        assert!(stem.len() < 170);
        assert_ne!(stem_of(&format!("{long}y")), stem);
        assert_eq!(
            staging_pid(&format!(".{stem}.tmp-42-a1B2c3")),
            Some((stem.as_str(), 42))
        );
        assert_eq!(staging_pid(".a.tmp-42-toolong"), None);
        assert_eq!(staging_pid("a.tmp-42-a1b2c3"), None);
    }
}
