//! Files kin writes, written so that a user's work is never lost: a crash, a kill, a full disk
//! or a concurrent writer leaves either the old complete file or the new complete file.
//!
//! [`replace`] writes a temporary file in the target's directory and renames it over the target
//! (a rename within one file system is atomic); [`create_new`] does the same for a file that must
//! not exist yet, and never replaces one; [`check_target`] refuses, before any work is
//! done, an output that is one of the command's inputs or whose directory does not exist;
//! [`lock_beside`] takes an advisory lock on a small lock file next to a file that several
//! processes may rewrite.

use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use thiserror::Error;

/// Why an output path cannot be used.
#[derive(Debug, Error)]
pub enum TargetError {
    #[error("`{}` cannot be written: the folder `{}` does not exist", output.display(), dir.display())]
    NoDirectory { output: PathBuf, dir: PathBuf },
    #[error("`{}` cannot be written: it is a folder", output.display())]
    IsDirectory { output: PathBuf },
    #[error("`{}` is also an input of this command (`{}`); writing it would destroy the input, choose another output", output.display(), input.display())]
    IsInput { output: PathBuf, input: PathBuf },
}

/// Checks, before any expensive work, that `output` can be created or replaced without
/// touching `inputs`: its folder exists, it is not a folder, and it is not the same file as
/// any input (by device and inode on Unix, so another spelling or a hard link is caught too).
pub fn check_target(output: &Path, inputs: &[&Path]) -> Result<(), TargetError> {
    let dir = directory_of(output);
    if !dir.is_dir() {
        return Err(TargetError::NoDirectory {
            output: output.to_path_buf(),
            dir,
        });
    }
    if output.is_dir() {
        return Err(TargetError::IsDirectory {
            output: output.to_path_buf(),
        });
    }
    match inputs.iter().find(|i| same_file(output, i)) {
        Some(input) => Err(TargetError::IsInput {
            output: output.to_path_buf(),
            input: input.to_path_buf(),
        }),
        None => Ok(()),
    }
}

/// Whether two paths name the same file: for two existing files, by identity (device and inode
/// on Unix); otherwise by where they point — the same name in the same folder however spelled
/// (`./fit.json` and `fit.json`), so that an output is caught naming an input that does not
/// exist yet (a model's first history) or another output of the same command.
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(ma), Ok(mb)) => same_identity(a, &ma, b, &mb),
        _ => match (location(a), location(b)) {
            (Some(x), Some(y)) => x == y,
            _ => a == b,
        },
    }
}

/// A path's folder, resolved, and its name: where it points whether it exists or not.
fn location(path: &Path) -> Option<(PathBuf, std::ffi::OsString)> {
    let name = path.file_name()?.to_os_string();
    let dir = directory_of(path).canonicalize().ok()?;
    Some((dir, name))
}

#[cfg(unix)]
fn same_identity(_: &Path, a: &std::fs::Metadata, _: &Path, b: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    a.dev() == b.dev() && a.ino() == b.ino()
}

#[cfg(not(unix))]
fn same_identity(a: &Path, _: &std::fs::Metadata, b: &Path, _: &std::fs::Metadata) -> bool {
    matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

/// The folder a file is in (`.` for a bare file name).
fn directory_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Replaces `path` with `contents`, atomically: the bytes go to a temporary file next to it
/// (`.NAME.XXXXXX.tmp`), which is flushed to disk and renamed over `path`; then the folder is
/// flushed so the rename itself survives a power cut. On any error `path` is untouched and the
/// temporary file removed (a process killed mid-write can leave the temporary file, never a cut
/// `path`). A replaced file keeps its permissions (and its owner, where the system allows); one
/// the user may not write is refused as an in-place write would be; a symbolic link is
/// followed, so the file it points to is replaced and the link stays.
///
/// `-` is standard output, as for most command-line tools.
pub fn replace(path: &Path, contents: &[u8]) -> io::Result<()> {
    if path == Path::new("-") {
        let mut out = io::stdout().lock();
        out.write_all(contents)?;
        return out.flush();
    }
    if is_stream(path) {
        return write_stream(path, contents);
    }
    stage(path, contents)?.commit()
}

/// Where a symbolic link finally points, even when nothing is there yet (a dangling link names
/// the file to create): each link's target read and, when relative, taken from the link's
/// folder; at most 40 links, as the system's own resolution allows.
fn resolve_link(path: &Path) -> io::Result<PathBuf> {
    let mut at = path.to_path_buf();
    for _ in 0..40 {
        match std::fs::symlink_metadata(&at) {
            Ok(m) if m.file_type().is_symlink() => {
                let to = std::fs::read_link(&at)?;
                at = if to.is_absolute() {
                    to
                } else {
                    directory_of(&at).join(to)
                };
            }
            _ => return Ok(at),
        }
    }
    Err(io::Error::other(format!(
        "`{}`: too many levels of symbolic links",
        path.display()
    )))
}

/// Creates `path` with `contents`, atomically, and never over an existing file: the bytes go to
/// a temporary file next to it, flushed to disk, which is then moved to `path` only if nothing
/// is there (a rename that refuses to replace, or a hard link, decided by the file system at
/// that moment, so a file that appears meanwhile is not lost either). A `path` that exists —
/// a file, a folder, a symbolic link even dangling — is an error of kind
/// [`io::ErrorKind::AlreadyExists`], and nothing is written.
pub fn create_new(path: &Path, contents: &[u8]) -> io::Result<()> {
    if std::fs::symlink_metadata(path).is_ok() {
        return Err(io::Error::new(
            io::ErrorKind::AlreadyExists,
            "the file exists already",
        ));
    }
    let staged = stage(path, contents)?;
    staged
        .temp
        .persist_noclobber(&staged.target)
        .map_err(|e| e.error)?;
    sync_directory(&staged.dir)
}

/// Whether `path` names something that is not a file to replace: a device (`/dev/null`,
/// `/dev/stdout`), a pipe (`-o >(gzip > x)`, a FIFO) or a socket. Renaming a temporary file
/// over it would put a regular file in its place (as root, over the system's `/dev/null`) and
/// the reader would get nothing: such an output is written to, in place, instead.
fn is_stream(path: &Path) -> bool {
    std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir())
}

/// Writes `contents` to a device or pipe as any program writing to it would.
fn write_stream(path: &Path, contents: &[u8]) -> io::Result<()> {
    let mut f = std::fs::OpenOptions::new().write(true).open(path)?;
    f.write_all(contents)?;
    f.flush()
}

/// Replaces several files as one set, as far as a file system allows: every file's bytes are
/// written and flushed to its temporary file first, and only when all of them are on disk are
/// they renamed over their targets, one after the other. A failure while writing (a full disk,
/// a read-only target) replaces none of them; what can still interleave is only the renames.
pub fn replace_all(files: &[(&Path, &[u8])]) -> io::Result<()> {
    let (streams, files): (Vec<_>, Vec<_>) = files.iter().partition(|(path, _)| is_stream(path));
    let staged = files
        .iter()
        .map(|(path, contents)| stage(path, contents))
        .collect::<io::Result<Vec<Staged>>>()?;
    staged.into_iter().try_for_each(Staged::commit)?;
    // Devices and pipes take their bytes once the files are in place.
    streams
        .iter()
        .try_for_each(|(path, contents)| write_stream(path, contents))
}

/// A file's new contents on disk beside it, not yet renamed over it; dropped, it is removed.
struct Staged {
    temp: tempfile::NamedTempFile,
    target: PathBuf,
    dir: PathBuf,
}

impl Staged {
    fn commit(self) -> io::Result<()> {
        self.temp.persist(&self.target).map_err(|e| e.error)?;
        sync_directory(&self.dir)
    }
}

/// The first half of [`replace`]: the temporary file written and flushed.
fn stage(path: &Path, contents: &[u8]) -> io::Result<Staged> {
    let target = resolve_link(path)?;
    let dir = directory_of(&target);
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let existing = std::fs::metadata(&target).ok();
    if existing.is_some() {
        // Renaming would replace a file the user may not write (read-only): ask the system, as
        // an in-place write would, by opening it for writing without truncating it.
        std::fs::OpenOptions::new().write(true).open(&target)?;
    }
    let prefix = format!(".{name}.");
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".tmp");
    #[cfg(unix)]
    if existing.is_none() {
        // A new file gets what any new file would (0666 less the umask), not the 0600 of a
        // temporary file.
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o666));
    }
    let mut temp = builder.tempfile_in(&dir)?;
    if let Some(m) = &existing {
        temp.as_file().set_permissions(m.permissions())?;
        keep_owner(temp.as_file(), m);
    }
    temp.write_all(contents)?;
    temp.as_file().sync_all()?;
    Ok(Staged { temp, target, dir })
}

/// Gives the new file the replaced file's owner and group where the system allows it (root
/// replacing a user's file); elsewhere the new file is the writer's, as any file it creates.
#[cfg(unix)]
fn keep_owner(file: &File, was: &std::fs::Metadata) {
    use std::os::unix::fs::MetadataExt;
    // Best effort by design: an ordinary user cannot give a file away, and that is no reason
    // to fail the write.
    let _ = std::os::unix::fs::fchown(file, Some(was.uid()), Some(was.gid()));
}

#[cfg(not(unix))]
fn keep_owner(_: &File, _: &std::fs::Metadata) {}

#[cfg(unix)]
fn sync_directory(dir: &Path) -> io::Result<()> {
    File::open(dir)?.sync_all()
}

#[cfg(not(unix))]
fn sync_directory(_: &Path) -> io::Result<()> {
    // Directories cannot be opened as files here; the rename is as durable as the system makes it.
    Ok(())
}

/// `path` with `suffix` appended to its file name: `model.kin` + `.lock` → `model.kin.lock`.
pub fn beside(path: &Path, suffix: &str) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(suffix);
    PathBuf::from(p)
}

/// An exclusive advisory lock, held until dropped.
#[derive(Debug)]
pub struct Lock {
    _file: File,
}

/// Takes an exclusive advisory lock on `PATH.lock` (created if missing), waiting for another
/// holder to release it. The lock file is left in place: removing it would let two processes
/// lock two different files of the same name.
pub fn lock_beside(path: &Path) -> io::Result<Lock> {
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(beside(path, ".lock"))?;
    file.lock()?;
    Ok(Lock { _file: file })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir() -> tempfile::TempDir {
        tempfile::tempdir().expect("temp dir")
    }

    /// Two spellings of a file that does not exist yet are one file: an output is caught
    /// naming a model's first history or another output of the same command.
    #[test]
    fn paths_not_yet_written_are_compared_by_where_they_point() {
        let d = dir();
        let a = d.path().join("fit.json");
        let b = d.path().join(".").join("fit.json");
        assert!(same_file(&a, &b));
        assert!(!same_file(&a, &d.path().join("other.json")));
        assert!(check_target(&a, &[&b]).is_err());
        std::fs::write(&a, b"x").unwrap();
        assert!(same_file(&a, &b));
    }

    /// A device stays a device, and a pipe's reader gets the bytes: neither is replaced by a
    /// regular file. (`mkfifo` makes the pipe; the reader runs beside the write.)
    #[cfg(unix)]
    #[test]
    fn devices_and_pipes_are_written_to_not_replaced() {
        use std::os::unix::fs::FileTypeExt;
        replace(Path::new("/dev/null"), b"nothing").unwrap();
        replace_all(&[(Path::new("/dev/null"), b"nothing" as &[u8])]).unwrap();
        let kind = std::fs::metadata("/dev/null").unwrap().file_type();
        assert!(kind.is_char_device());

        let d = dir();
        let fifo = d.path().join("pipe");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if !made.is_ok_and(|s| s.success()) {
            return; // no mkfifo on this system
        }
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        let regular = d.path().join("table.txt");
        replace_all(&[(&fifo, b"streamed" as &[u8]), (&regular, b"kept")]).unwrap();
        assert_eq!(reader.join().unwrap(), b"streamed");
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        assert_eq!(std::fs::read(&regular).unwrap(), b"kept");
    }

    #[test]
    fn create_new_writes_a_new_file_and_never_an_existing_one() {
        let d = dir();
        let p = d.path().join("machine.kin");
        create_new(&p, b"first").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"first");
        let again = create_new(&p, b"second").unwrap_err();
        assert_eq!(again.kind(), io::ErrorKind::AlreadyExists);
        assert_eq!(std::fs::read(&p).unwrap(), b"first");
        // A folder of that name is not replaced either, and no temporary file is left.
        let folder = d.path().join("folder");
        std::fs::create_dir(&folder).unwrap();
        assert!(create_new(&folder, b"x").is_err());
        let names: Vec<_> = std::fs::read_dir(d.path()).unwrap().collect();
        assert_eq!(names.len(), 2, "{names:?}");
    }

    #[test]
    fn replace_creates_and_replaces_leaving_no_temporary_file() {
        let d = dir();
        let p = d.path().join("out.json");
        replace(&p, b"first").unwrap();
        replace(&p, b"second, longer").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"second, longer");
        let names: Vec<_> = std::fs::read_dir(d.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }

    #[cfg(unix)]
    #[test]
    fn replace_keeps_permissions_and_follows_a_link() {
        use std::os::unix::fs::PermissionsExt;
        let d = dir();
        let p = d.path().join("model.kin");
        std::fs::write(&p, "old").unwrap();
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o640)).unwrap();
        let link = d.path().join("link.kin");
        std::os::unix::fs::symlink(&p, &link).unwrap();
        replace(&link, b"new").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "new");
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        let mode = std::fs::metadata(&p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o640);
    }

    /// A dangling link names the file to create (it failed with "No such file"); a chain of
    /// links is followed to its end, relative targets from each link's folder.
    #[cfg(unix)]
    #[test]
    fn a_dangling_link_is_followed_to_the_file_it_names() {
        let d = dir();
        std::fs::create_dir(d.path().join("sub")).unwrap();
        let link = d.path().join("out.csv");
        std::os::unix::fs::symlink("sub/chain.csv", &link).unwrap();
        std::os::unix::fs::symlink("real.csv", d.path().join("sub/chain.csv")).unwrap();
        replace(&link, b"new").unwrap();
        assert_eq!(
            std::fs::read_to_string(d.path().join("sub/real.csv")).unwrap(),
            "new"
        );
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        let looped = d.path().join("loop.csv");
        std::os::unix::fs::symlink("loop.csv", &looped).unwrap();
        assert!(replace(&looped, b"x").is_err());
    }

    #[test]
    fn a_file_that_cannot_be_written_is_not_replaced() {
        let d = dir();
        let p = d.path().join("locked.json");
        std::fs::write(&p, "old").unwrap();
        let mut perms = std::fs::metadata(&p).unwrap().permissions();
        perms.set_readonly(true);
        std::fs::set_permissions(&p, perms).unwrap();
        // Root may write anything: then the file is replaced, as an in-place write would be.
        let writable = std::fs::OpenOptions::new().write(true).open(&p).is_ok();
        assert_eq!(replace(&p, b"new").is_ok(), writable);
        let expected = if writable { "new" } else { "old" };
        assert_eq!(std::fs::read_to_string(&p).unwrap(), expected);
        assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_set_is_replaced_whole_or_not_at_all() {
        let d = dir();
        let (a, b) = (d.path().join("X.comp"), d.path().join("Y.comp"));
        std::fs::write(&a, "old X").expect("write");
        std::fs::write(&b, "old Y").expect("write");
        replace_all(&[(&a, b"new X"), (&b, b"new Y")]).expect("both");
        assert_eq!(std::fs::read_to_string(&a).expect("read"), "new X");
        assert_eq!(std::fs::read_to_string(&b).expect("read"), "new Y");
        // The second cannot be written (its folder is missing): the first stays as it was.
        let missing = d.path().join("gone").join("Z.comp");
        assert!(replace_all(&[(&a, b"newer X"), (&missing, b"Z")]).is_err());
        assert_eq!(std::fs::read_to_string(&a).expect("read"), "new X");
        let left: Vec<_> = std::fs::read_dir(d.path())
            .expect("list")
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
            .collect();
        assert!(left.is_empty(), "temporary files left: {left:?}");
    }

    #[test]
    fn replace_into_a_missing_folder_fails_and_creates_nothing() {
        let d = dir();
        let p = d.path().join("missing").join("out.json");
        assert!(replace(&p, b"x").is_err());
        assert!(!d.path().join("missing").exists());
    }

    #[test]
    fn a_target_that_is_an_input_is_refused_under_another_spelling() {
        let d = dir();
        let input = d.path().join("data.csv");
        std::fs::write(&input, "x").unwrap();
        let other = d.path().join(".").join("data.csv");
        assert!(matches!(
            check_target(&other, &[&input]),
            Err(TargetError::IsInput { .. })
        ));
        #[cfg(unix)]
        {
            let hard = d.path().join("hard.csv");
            std::fs::hard_link(&input, &hard).unwrap();
            assert!(check_target(&hard, &[&input]).is_err());
        }
        assert!(check_target(&d.path().join("new.csv"), &[&input]).is_ok());
        assert!(matches!(
            check_target(&d.path().join("no/such.csv"), &[&input]),
            Err(TargetError::NoDirectory { .. })
        ));
        assert!(matches!(
            check_target(d.path(), &[&input]),
            Err(TargetError::IsDirectory { .. })
        ));
    }
}
