//! A set of files replaced as one: a controller's compensation tables and their note
//! (`kin compensate --table`, spec/cli.md "Files kin writes").
//!
//! Renaming the files one by one leaves, after a kill between two renames, a new `X.comp`
//! beside an old `Y.comp`; writing a set over fewer axes into the folder of an earlier one
//! leaves that set's `Y.comp`, which a controller loading the folder keeps using. So the new
//! set is written into a fresh folder beside the old one, the files of the folder that are not
//! kin's (the controller's own, by hard link) are carried over, and the two folders are
//! exchanged by one `renameat2(RENAME_EXCHANGE)`: a reader sees the old folder or the new one,
//! never a mix, and a table of an earlier set that the new one does not have is gone with the
//! old folder. Where the system cannot exchange (not Linux, a file system without it), the old
//! folder is renamed aside and the new one into its place, then the old removed: a kill in
//! between leaves the old set whole under its aside name, and the message says where.

use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

/// What [`replace_folder`] did besides writing the set.
#[derive(Debug, Default)]
pub struct Replaced {
    /// Files of an earlier set that the new one does not have, removed with it.
    pub stale: Vec<String>,
    /// Other files of the folder, carried over unchanged.
    pub kept: Vec<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum FolderError {
    #[error("`{folder}` holds `{name}`, which is not a file: tables go into a folder of files (move it, or write the tables elsewhere)")]
    NotAFile { folder: String, name: String },
    #[error("{0}")]
    Io(#[from] io::Error),
}

/// Whether the file at `path` was written by kin as part of a table set: its first 4 KiB hold
/// `marker` (every table and note kin writes names its origin in a comment).
pub fn written_by(path: &Path, marker: &str) -> bool {
    let Ok(file) = std::fs::File::open(path) else {
        return false;
    };
    let mut head = Vec::with_capacity(4096);
    if file.take(4096).read_to_end(&mut head).is_err() {
        return false;
    }
    String::from_utf8_lossy(&head).contains(marker)
}

/// Replaces the folder `folder` (created when it does not exist) by one holding `files` and
/// the folder's other files; files of an earlier set (`ours`) that `files` does not name are
/// dropped.
pub fn replace_folder(
    folder: &Path,
    files: &[(String, &[u8])],
    ours: impl Fn(&Path) -> bool,
) -> Result<Replaced, FolderError> {
    let target = match std::fs::symlink_metadata(folder) {
        Ok(m) if m.file_type().is_symlink() => folder.canonicalize()?,
        _ => folder.to_path_buf(),
    };
    let parent = match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "tables".into());
    let existing = std::fs::metadata(&target).ok().filter(|m| m.is_dir());
    // Checked before anything is written: a folder inside cannot be carried over.
    let mut carried = Vec::new();
    let mut replaced = Replaced::default();
    if existing.is_some() {
        let mut entries: Vec<_> = std::fs::read_dir(&target)?.collect::<Result<_, _>>()?;
        entries.sort_by_key(|e| e.file_name());
        for entry in entries {
            let entry_name = entry.file_name().to_string_lossy().into_owned();
            if files.iter().any(|(n, _)| *n == entry_name) {
                continue;
            }
            let kind = entry.file_type()?;
            if kind.is_file() && ours(&entry.path()) {
                replaced.stale.push(entry_name);
            } else if kind.is_file() || kind.is_symlink() {
                carried.push((entry.path(), entry_name.clone(), kind.is_symlink()));
                replaced.kept.push(entry_name);
            } else {
                return Err(FolderError::NotAFile {
                    folder: target.display().to_string(),
                    name: entry_name,
                });
            }
        }
    }
    let staged = fresh_folder(&parent, &name)?;
    let result = (|| -> Result<(), FolderError> {
        if let Some(m) = &existing {
            std::fs::set_permissions(&staged, m.permissions())?;
        }
        for (file, contents) in files {
            let path = staged.join(file);
            let mut f = std::fs::File::create(&path)?;
            f.write_all(contents)?;
            f.sync_all()?;
        }
        for (from, entry_name, link) in &carried {
            let to = staged.join(entry_name);
            if *link {
                #[cfg(unix)]
                std::os::unix::fs::symlink(std::fs::read_link(from)?, &to)?;
                #[cfg(not(unix))]
                std::fs::copy(from, &to)?;
            } else if std::fs::hard_link(from, &to).is_err() {
                // A file system without hard links: a copy keeps the contents.
                std::fs::copy(from, &to)?;
            }
        }
        sync(&staged);
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_dir_all(&staged);
        return Err(e);
    }
    if existing.is_none() {
        if let Err(e) = std::fs::rename(&staged, &target) {
            let _ = std::fs::remove_dir_all(&staged);
            return Err(e.into());
        }
        sync(&parent);
        return Ok(replaced);
    }
    match exchange(&staged, &target) {
        Ok(()) => {
            // `staged` now names the old folder.
            sync(&parent);
            let _ = std::fs::remove_dir_all(&staged);
        }
        Err(_) => {
            let aside = fresh_name(&parent, &format!("{name}.old"));
            std::fs::rename(&target, &aside)?;
            if let Err(e) = std::fs::rename(&staged, &target) {
                // Put the old set back where it was.
                let _ = std::fs::rename(&aside, &target);
                let _ = std::fs::remove_dir_all(&staged);
                return Err(e.into());
            }
            sync(&parent);
            let _ = std::fs::remove_dir_all(&aside);
        }
    }
    Ok(replaced)
}

/// Exchanges two paths in one step (Linux `renameat2` with `RENAME_EXCHANGE`).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let a = CString::new(a.as_os_str().as_bytes()).map_err(io::Error::other)?;
    let b = CString::new(b.as_os_str().as_bytes()).map_err(io::Error::other)?;
    // SAFETY: both are valid NUL-terminated paths that outlive the call; the call reads them
    // and nothing else.
    let rc = unsafe {
        libc::syscall(
            libc::SYS_renameat2,
            libc::AT_FDCWD,
            a.as_ptr(),
            libc::AT_FDCWD,
            b.as_ptr(),
            libc::RENAME_EXCHANGE,
        )
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> io::Result<()> {
    Err(io::Error::from(io::ErrorKind::Unsupported))
}

/// A new, empty folder `.NAME.kin-…` in `parent` (its mode what any new folder gets).
fn fresh_folder(parent: &Path, name: &str) -> io::Result<PathBuf> {
    for _ in 0..100 {
        let path = fresh_name(parent, name);
        match std::fs::create_dir(&path) {
            Ok(()) => return Ok(path),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(io::Error::other("no free name for a temporary folder"))
}

/// `.NAME.kin-PID-N.tmp` in `parent`, N from the clock (a name, not a guarantee: the caller
/// creates it exclusively or renames onto it).
fn fresh_name(parent: &Path, name: &str) -> PathBuf {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    parent.join(format!(".{name}.kin-{}-{nanos}.tmp", std::process::id()))
}

/// Flushes a folder's entries to disk (best effort: not every system can open a folder).
fn sync(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MARK: &str = "written by kin from";

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_smaller_set_leaves_no_stale_table_and_keeps_the_controllers_files() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("tables");
        let first = [
            (
                "X.comp".to_string(),
                b"# written by kin from a\n1 2\n".as_slice(),
            ),
            (
                "Y.comp".to_string(),
                b"# written by kin from a\n3 4\n".as_slice(),
            ),
        ];
        replace_folder(&dir, &first, |p| written_by(p, MARK)).unwrap();
        std::fs::write(dir.join("machine.ini"), "[JOINT_0]\n").unwrap();
        let ino = |p: &Path| {
            use std::os::unix::fs::MetadataExt;
            std::fs::metadata(p).unwrap().ino()
        };
        let ini = ino(&dir.join("machine.ini"));
        let second = [(
            "X.comp".to_string(),
            b"# written by kin from b\n5 6\n".as_slice(),
        )];
        let r = replace_folder(&dir, &second, |p| written_by(p, MARK)).unwrap();
        assert_eq!(r.stale, vec!["Y.comp"]);
        assert_eq!(r.kept, vec!["machine.ini"]);
        assert_eq!(names(&dir), vec!["X.comp", "machine.ini"]);
        assert_eq!(
            std::fs::read_to_string(dir.join("X.comp")).unwrap(),
            "# written by kin from b\n5 6\n"
        );
        // The controller's file is the same file, not a copy.
        assert_eq!(ino(&dir.join("machine.ini")), ini);
        // No temporary folder is left beside it.
        assert_eq!(names(root.path()), vec!["tables"]);
    }

    #[test]
    fn a_folder_inside_is_refused_and_nothing_changes() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("tables");
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(dir.join("Y.comp"), "# written by kin from a\n").unwrap();
        let set = [("X.comp".to_string(), b"new".as_slice())];
        let e = replace_folder(&dir, &set, |p| written_by(p, MARK)).unwrap_err();
        assert!(e.to_string().contains("`sub`"), "{e}");
        assert_eq!(names(&dir), vec!["Y.comp", "sub"]);
        assert_eq!(names(root.path()), vec!["tables"]);
    }
}
