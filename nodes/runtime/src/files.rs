//! Replacing a file without ever leaving half of it: the new content goes to a temporary file
//! beside it, renamed over it only once complete. Model files, recordings' recovered copies and
//! statistics all write this way.

use std::fs::File;
use std::io::Write;
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

#[cfg(test)]
mod tests {
    use super::*;

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
