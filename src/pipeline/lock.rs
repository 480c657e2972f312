//! The exclusive lock on a data folder: one process at a time recovers, claims and commits in
//! it. Two daemons on one folder would move each other's in-flight scans and match them twice;
//! the second one refuses to start instead, naming the first one's process id.
//!
//! The lock is an advisory `flock` on `DATA/.lock` (through the `fs4` crate), held as long as
//! the [`DataLock`] lives; the kernel releases it when the process ends, even after `kill -9`,
//! so a stale lock file never blocks a restart. The holder writes its PID into the file.
//! (Several workers on one queue are the scale-out design's job, not this lock's.)

use std::{
    fs::{File, OpenOptions},
    io::{Read, Seek, SeekFrom, Write},
    path::{Path, PathBuf},
};

use fs4::{FileExt, TryLockError};

use super::error::Error;

/// An exclusive lock on a data folder, released when dropped (or when the process ends).
#[derive(Debug)]
pub struct DataLock {
    file: File,
    path: PathBuf,
}

impl DataLock {
    /// Takes the lock on `root/.lock` without waiting. Fails with a message naming the
    /// holder's PID when another process holds it.
    ///
    /// ```
    /// use shapeforest::pipeline::DataLock;
    /// let d = tempfile::tempdir().unwrap();
    /// let held = DataLock::acquire(d.path()).unwrap();
    /// let e = DataLock::acquire(d.path()).unwrap_err();
    /// assert!(e.to_string().contains(&format!("PID {}", std::process::id())), "{e}");
    /// drop(held);
    /// assert!(DataLock::acquire(d.path()).is_ok());
    /// ```
    pub fn acquire(root: &Path) -> Result<DataLock, Error> {
        std::fs::create_dir_all(root).map_err(|e| Error::io(root, e))?;
        let path = root.join(".lock");
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| Error::Lock(format!("{}: cannot open the lock file: {e}", path.display())))?;
        // Called through the trait: `File` has an inherent `try_lock` on newer toolchains.
        match FileExt::try_lock(&file) {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let mut text = String::new();
                let _ = file.read_to_string(&mut text);
                let holder = text.lines().next().unwrap_or("").trim();
                let holder = match holder.parse::<u32>() {
                    Ok(pid) => format!("PID {pid}"),
                    Err(_) => "a process that has not written its PID yet".to_string(),
                };
                return Err(Error::Lock(format!(
                    "the data folder {} is in use by another shapeforest process ({holder}; lock \
                     file {}): stop it first, or give this one its own --data-dir",
                    root.display(),
                    path.display()
                )));
            }
            Err(TryLockError::Error(e)) => {
                return Err(Error::Lock(format!("{}: cannot lock: {e}", path.display())))
            }
        }
        let write = (|| {
            file.set_len(0)?;
            file.seek(SeekFrom::Start(0))?;
            writeln!(file, "{}", std::process::id())?;
            file.flush()
        })();
        write.map_err(|e| Error::Lock(format!("{}: cannot write the lock file: {e}", path.display())))?;
        Ok(DataLock { file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for DataLock {
    fn drop(&mut self) {
        let _ = FileExt::unlock(&self.file);
    }
}
