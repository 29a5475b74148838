//! Where a BIDS dataset's files go: a directory that appears under its name only when every
//! file is written (nothing half-written is ever a dataset), or a zip streamed as it is made.

use std::path::{Path, PathBuf};

use async_zip::tokio::write::ZipFileWriter;
use async_zip::{Compression, ZipEntryBuilder};
use tokio::io::{AsyncWrite, AsyncWriteExt};

use super::super::ExportError;
use crate::error::AppError;

/// Takes the dataset's files one at a time, by their path from the dataset's root.
pub trait DatasetSink {
    fn file(
        &mut self,
        path: &str,
        bytes: &[u8],
    ) -> impl std::future::Future<Output = Result<(), ExportError>> + Send;
}

/// A dataset directory: written under `<out>.partial`, renamed to `out` by [`DirSink::finish`]
/// and removed when dropped unfinished.
#[derive(Debug)]
pub struct DirSink {
    partial: PathBuf,
    out: PathBuf,
    finished: bool,
}

impl DirSink {
    /// Refuses an `out` that exists (an export never overwrites) or whose parent is missing.
    pub fn create(out: &Path) -> Result<Self, ExportError> {
        if out.exists() {
            return Err(AppError::Conflict(format!(
                "{} exists: a BIDS export never overwrites; choose a new directory",
                out.display()
            ))
            .into());
        }
        if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty())
            && !parent.is_dir()
        {
            return Err(AppError::BadRequest(format!(
                "{}: no such directory for the BIDS export",
                parent.display()
            ))
            .into());
        }
        let mut partial = out.as_os_str().to_owned();
        partial.push(".partial");
        let partial = PathBuf::from(partial);
        if partial.exists() {
            // Left by an export that was killed: never a dataset, safe to remove.
            std::fs::remove_dir_all(&partial)?;
        }
        // Subject data, like the database: the owner's only (`crate::files`).
        crate::files::create_private_dirs(&partial)?;
        Ok(Self {
            partial,
            out: out.to_path_buf(),
            finished: false,
        })
    }

    /// Gives the complete dataset its name.
    pub fn finish(mut self) -> Result<(), ExportError> {
        std::fs::rename(&self.partial, &self.out)?;
        self.finished = true;
        Ok(())
    }
}

impl Drop for DirSink {
    fn drop(&mut self) {
        if !self.finished {
            let _ = std::fs::remove_dir_all(&self.partial);
        }
    }
}

impl DatasetSink for DirSink {
    async fn file(&mut self, path: &str, bytes: &[u8]) -> Result<(), ExportError> {
        let path = self.partial.join(path);
        if let Some(dir) = path.parent() {
            tokio::fs::DirBuilder::new()
                .recursive(true)
                .mode(crate::files::DIR_MODE)
                .create(dir)
                .await?;
        }
        let mut file = tokio::fs::OpenOptions::from(crate::files::new_private())
            .open(&path)
            .await?;
        file.write_all(bytes).await?;
        file.flush().await?;
        Ok(())
    }
}

/// A zip of the dataset, written entry by entry (deflated) into `W`.
pub struct ZipSink<W: AsyncWrite + Unpin> {
    zip: ZipFileWriter<W>,
    /// The folder every entry sits in (the dataset's name), so that unzipping makes one.
    root: String,
}

impl<W: AsyncWrite + Unpin + Send> ZipSink<W> {
    pub fn new(out: W, root: &str) -> Self {
        Self {
            zip: ZipFileWriter::with_tokio(out),
            root: root.to_string(),
        }
    }

    /// Writes the zip's directory: without it the zip is not readable.
    pub async fn finish(self) -> Result<(), ExportError> {
        self.zip.close().await.map_err(zip_error)?;
        Ok(())
    }
}

impl<W: AsyncWrite + Unpin> std::fmt::Debug for ZipSink<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZipSink").field("root", &self.root).finish()
    }
}

fn zip_error(e: async_zip::error::ZipError) -> ExportError {
    ExportError::Io(std::io::Error::other(e))
}

impl<W: AsyncWrite + Unpin + Send> DatasetSink for ZipSink<W> {
    async fn file(&mut self, path: &str, bytes: &[u8]) -> Result<(), ExportError> {
        let name = format!("{}/{path}", self.root);
        let entry = ZipEntryBuilder::new(name.into(), Compression::Deflate);
        self.zip
            .write_entry_whole(entry, bytes)
            .await
            .map_err(zip_error)
    }
}
