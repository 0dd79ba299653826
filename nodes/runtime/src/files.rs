//! Replacing a file without ever leaving half of it: the new content goes to a temporary file
//! beside it, renamed over it only once complete. Model files, recordings' recovered copies and
//! statistics all write this way.
//!
//! And reading a file a user named ([`open_regular`], [`read_bounded`]): only a regular file, so
//! that `/dev/zero`, a FIFO or a folder given as a model or a recording is refused by its kind
//! before anything is read, and (models) only up to a documented size.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// A temporary file that becomes `path` on [`Replacement::commit`], and is removed if dropped
/// before.
pub struct Replacement {
    path: PathBuf,
    temp: Option<PathBuf>,
}

impl Replacement {
    /// Creates the temporary file for `path` (and `path`'s folder); a symlink at `path` is
    /// followed, so that its target is replaced and the link kept.
    pub fn create(path: &Path) -> std::io::Result<(Replacement, File)> {
        let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
        let path = match is_link {
            true => std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()),
            false => path.to_path_buf(),
        };
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir)?;
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let mut attempt = 0u32;
        loop {
            let temp = dir.join(format!(".{name}.{}-{attempt}.tmp", std::process::id()));
            match std::fs::OpenOptions::new().write(true).create_new(true).open(&temp) {
                Ok(file) => return Ok((Replacement { path, temp: Some(temp) }, file)),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && attempt < 100 => attempt += 1,
                Err(e) => return Err(e),
            }
        }
    }

    /// Renames the temporary file over the path (its content written and synced by the caller).
    pub fn commit(mut self) -> std::io::Result<()> {
        let Some(temp) = self.temp.take() else { return Ok(()) };
        if let Err(e) = std::fs::rename(&temp, &self.path) {
            std::fs::remove_file(&temp).ok();
            return Err(e);
        }
        // The rename itself made durable, best effort.
        if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty()) {
            File::open(dir).and_then(|d| d.sync_all()).ok();
        }
        Ok(())
    }
}

impl Drop for Replacement {
    fn drop(&mut self) {
        if let Some(temp) = self.temp.take() {
            std::fs::remove_file(temp).ok();
        }
    }
}

/// Writes `bytes` as the new content of `path` through a [`Replacement`].
pub fn replace_file(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let (replacement, mut file) = Replacement::create(path)?;
    file.write_all(bytes)?;
    file.sync_all()?;
    replacement.commit()
}

/// Writes `value` as CBOR as the new content of `path` through a [`Replacement`], streamed (a
/// shard's records, a study's results).
pub fn replace_cbor<T: serde::Serialize>(path: &Path, value: &T) -> std::io::Result<()> {
    let (replacement, file) = Replacement::create(path)?;
    let mut w = std::io::BufWriter::new(file);
    ciborium::into_writer(value, &mut w).map_err(|e| std::io::Error::other(e.to_string()))?;
    w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    replacement.commit()
}

/// The most bytes a model file (`.dcg`, `.dcu`) may hold: 256 MiB, 64 million f32 weights. The
/// shipped models hold 10 KB (`.dcg`) and 0.7 MB (`.dcu`), a U-Net the size of the thesis's (2.7
/// million weights) 11 MB. Readers refuse a larger file before reading any of it, and trainers a
/// network whose weights alone would not fit.
pub const MAX_MODEL_BYTES: u64 = 256 << 20;

/// Why a file a user named was not read.
#[derive(Debug)]
pub enum UserFileError {
    /// Not a regular file: a directory, a FIFO, a device (`/dev/zero`), a socket.
    NotRegular {
        kind: &'static str,
        what: String,
    },
    /// More bytes than any file of its kind holds.
    TooLarge {
        size: u64,
        max: u64,
        what: String,
    },
    Io(std::io::Error),
}

impl std::fmt::Display for UserFileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            UserFileError::NotRegular { kind, what } => write!(f, "is {kind}, not a {what}"),
            UserFileError::TooLarge { size, max, what } => {
                write!(f, "is {}, larger than any {what} (at most {})", size_text(*size), size_text(*max))
            }
            UserFileError::Io(e) => std::fmt::Display::fmt(e, f),
        }
    }
}

impl std::error::Error for UserFileError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            UserFileError::Io(e) => std::error::Error::source(e),
            _ => None,
        }
    }
}

impl From<std::io::Error> for UserFileError {
    fn from(e: std::io::Error) -> Self {
        UserFileError::Io(e)
    }
}

/// For readers whose errors carry an `std::io::Error`: the same message (the I/O error itself,
/// or the refusal as an `InvalidInput` error).
impl From<UserFileError> for std::io::Error {
    fn from(e: UserFileError) -> Self {
        match e {
            UserFileError::Io(e) => e,
            other => std::io::Error::new(std::io::ErrorKind::InvalidInput, other),
        }
    }
}

/// `bytes` for a message: `3 GiB`, `1.5 MiB`, `12 bytes`.
pub fn size_text(bytes: u64) -> String {
    for (unit, name) in [(1u64 << 30, "GiB"), (1 << 20, "MiB"), (1 << 10, "KiB")] {
        if bytes >= unit {
            return match bytes % unit {
                0 => format!("{} {name}", bytes / unit),
                _ => format!("{:.1} {name}", bytes as f64 / unit as f64),
            };
        }
    }
    format!("{bytes} bytes")
}

/// What a file type is when it is not a regular file.
fn not_regular(file_type: std::fs::FileType) -> Option<&'static str> {
    if file_type.is_file() {
        return None;
    }
    if file_type.is_dir() {
        return Some("a directory");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if file_type.is_char_device() {
            return Some("a character device");
        }
        if file_type.is_block_device() {
            return Some("a block device");
        }
        if file_type.is_fifo() {
            return Some("a FIFO (named pipe)");
        }
        if file_type.is_socket() {
            return Some("a socket");
        }
    }
    Some("something other than a regular file")
}

/// Opens `path`, a file a user named as a `what` (`"model file"`, `"recording"`), for reading,
/// if it is a regular file (a symlink is followed): a directory, a FIFO, a device or a socket is
/// refused by its kind before it is opened (opening a FIFO waits for a writer, a device such as
/// `/dev/zero` never ends). The opened file is checked again, should the path have been
/// replaced in between. Errors do not repeat the path: the caller names it.
pub fn open_regular(path: &Path, what: &str) -> Result<File, UserFileError> {
    let check = |file_type| match not_regular(file_type) {
        Some(kind) => Err(UserFileError::NotRegular { kind, what: what.to_string() }),
        None => Ok(()),
    };
    check(std::fs::metadata(path)?.file_type())?;
    let file = File::open(path)?;
    check(file.metadata()?.file_type())?;
    Ok(file)
}

/// All of the regular file `path` (a `what`, see [`open_regular`]), refused without reading any
/// of it when it holds more than `max` bytes; at most the size it had when opened is read, so a
/// file that grows meanwhile cannot make the read run away.
pub fn read_bounded(path: &Path, what: &str, max: u64) -> Result<Vec<u8>, UserFileError> {
    let file = open_regular(path, what)?;
    let size = file.metadata()?.len();
    if size > max {
        return Err(UserFileError::TooLarge { size, max, what: what.to_string() });
    }
    let mut bytes = Vec::with_capacity(size as usize);
    file.take(size).read_to_end(&mut bytes)?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A FIFO at `path` (`mkfifo`).
    fn fifo(path: &Path) {
        let made = std::process::Command::new("mkfifo").arg(path).status().expect("run mkfifo");
        assert!(made.success(), "mkfifo {}", path.display());
    }

    #[test]
    fn only_regular_files_of_at_most_their_bound_are_read() {
        let dir = std::env::temp_dir().join(format!("dc-read-bounded-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good");
        std::fs::write(&good, b"twelve bytes").unwrap();
        assert_eq!(read_bounded(&good, "model file", 12).unwrap(), b"twelve bytes");
        let e = read_bounded(&good, "model file", 11).unwrap_err().to_string();
        assert_eq!(e, "is 12 bytes, larger than any model file (at most 11 bytes)");
        let pipe = dir.join("pipe");
        fifo(&pipe);
        // A sparse file: 3 GiB long, nothing written.
        let huge = dir.join("huge");
        File::create(&huge).unwrap().set_len(3 << 30).unwrap();
        let started = std::time::Instant::now();
        for (path, expected) in [
            (Path::new("/dev/zero"), "is a character device, not a model file"),
            (dir.as_path(), "is a directory, not a model file"),
            (pipe.as_path(), "is a FIFO (named pipe), not a model file"),
            (huge.as_path(), "is 3 GiB, larger than any model file (at most 256 MiB)"),
        ] {
            let e = read_bounded(path, "model file", MAX_MODEL_BYTES).unwrap_err();
            assert_eq!(e.to_string(), expected, "{}", path.display());
            // Through an I/O error, the same message.
            assert_eq!(std::io::Error::from(e).to_string(), expected);
        }
        let e = open_regular(&pipe, "recording").unwrap_err().to_string();
        assert_eq!(e, "is a FIFO (named pipe), not a recording");
        assert!(matches!(open_regular(&dir.join("missing"), "recording"), Err(UserFileError::Io(_))));
        assert!(started.elapsed() < std::time::Duration::from_secs(5), "{:?}", started.elapsed());
        assert_eq!(size_text(1536 << 10), "1.5 MiB");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_replacement_is_all_or_nothing() {
        let dir = std::env::temp_dir().join(format!("dc-replace-{}", std::process::id()));
        let path = dir.join("sub/file");
        replace_file(&path, b"first").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"first");
        // Dropped before its commit: the old content stays and no temporary is left.
        let (replacement, mut file) = Replacement::create(&path).unwrap();
        file.write_all(b"half").unwrap();
        drop(replacement);
        assert_eq!(std::fs::read(&path).unwrap(), b"first");
        assert_eq!(std::fs::read_dir(path.parent().unwrap()).unwrap().count(), 1);
        replace_file(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
