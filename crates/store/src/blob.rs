//! Recording blobs written from a file in chunks (SQLite incremental blob
//! I/O), so storing a large import does not hold its bytes in memory
//! (issue 11, decision 0021a). sqlx binds a blob as one buffer (and SQLite
//! copies it); `zeroblob(N)` reserves the space and `sqlite3_blob_write`
//! fills it 1 MiB at a time inside the caller's transaction.

use super::{StoreError, StoreResult};
use libsqlite3_sys as ffi;
use std::ffi::CStr;
use std::io::Read;
use std::path::Path;

/// Bytes per `sqlite3_blob_write`.
const CHUNK: usize = 1 << 20;

fn err(m: impl Into<String>) -> StoreError {
    StoreError::Corrupt(m.into())
}

/// Copies the file at `path` into `recording_blobs.bytes` of recording
/// `rowid`, which holds a `zeroblob` of exactly the file's length (the row's
/// only stored field, so SQLite does not expand it), on `conn` (the
/// transaction's connection).
pub(super) async fn fill_recording(
    conn: &mut sqlx::SqliteConnection,
    rowid: i64,
    path: &Path,
) -> StoreResult<()> {
    let mut file = std::fs::File::open(path)
        .map_err(|e| err(format!("recording file {}: {e}", path.display())))?;
    let mut handle = conn.lock_handle().await?;
    let db = handle.as_raw_handle().as_ptr();
    // `db` is the live connection held locked by `handle` for this whole
    // function; `blob` is closed below on every path.
    let blob = open_blob(db, c"recording_blobs", c"bytes", rowid, true)?;
    let mut buf = vec![0u8; CHUNK];
    let mut offset: usize = 0;
    let res = loop {
        let n = match file.read(&mut buf) {
            Ok(0) => break Ok(()),
            Ok(n) => n,
            Err(e) => break Err(err(format!("recording file: {e}"))),
        };
        let Ok(off) = i32::try_from(offset) else {
            break Err(err("recording larger than 2 GiB"));
        };
        // SAFETY: `blob` is open; `buf[..n]` is initialised and outlives the call.
        let rc = unsafe { ffi::sqlite3_blob_write(blob, buf.as_ptr().cast(), n as i32, off) };
        if rc != ffi::SQLITE_OK {
            break Err(err(format!("writing the recording blob: {}", message(db))));
        }
        offset += n;
    };
    // SAFETY: opened above, closed exactly once.
    let rc = unsafe { ffi::sqlite3_blob_close(blob) };
    res?;
    if rc != ffi::SQLITE_OK {
        return Err(err(format!("closing the recording blob: {}", message(db))));
    }
    Ok(())
}

/// Opens `main.table.column` of row `rowid` on `db`, which must be a live
/// connection held locked by the caller until the returned handle is closed
/// with `sqlite3_blob_close` (exactly once).
fn open_blob(
    db: *mut ffi::sqlite3,
    table: &CStr,
    column: &CStr,
    rowid: i64,
    writable: bool,
) -> StoreResult<*mut ffi::sqlite3_blob> {
    let mut blob: *mut ffi::sqlite3_blob = std::ptr::null_mut();
    // SAFETY: `db` is live and locked (the caller's contract); the names are
    // NUL-terminated C strings that outlive the call.
    let rc = unsafe {
        ffi::sqlite3_blob_open(
            db,
            c"main".as_ptr(),
            table.as_ptr(),
            column.as_ptr(),
            rowid,
            i32::from(writable),
            &mut blob,
        )
    };
    if rc != ffi::SQLITE_OK {
        return Err(err(format!("opening the recording blob: {}", message(db))));
    }
    Ok(blob)
}

fn message(db: *mut ffi::sqlite3) -> String {
    // SAFETY: sqlite3_errmsg returns a NUL-terminated string owned by the connection.
    unsafe {
        let p = ffi::sqlite3_errmsg(db);
        if p.is_null() {
            "unknown error".into()
        } else {
            CStr::from_ptr(p).to_string_lossy().into_owned()
        }
    }
}

/// A stored recording's bytes, read in chunks: `recording_blobs.bytes` (large
/// imports) or `recordings.wav` of recording `rowid`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlobRef {
    pub(crate) in_blobs: bool,
    pub(crate) rowid: i64,
    /// Bytes.
    pub len: u64,
}

/// Reads up to `buf.len()` bytes of `blob` from `offset` on `conn`, with a
/// blob handle opened and closed for this call (no read transaction stays
/// open between chunks; a blob removed meanwhile, e.g. by the retention
/// policy, is an error, not a stale read). Returns 0 at the end.
pub(super) async fn read_chunk(
    conn: &mut sqlx::SqliteConnection,
    blob_ref: &BlobRef,
    offset: u64,
    buf: &mut [u8],
) -> StoreResult<usize> {
    let (table, column) = if blob_ref.in_blobs {
        (c"recording_blobs", c"bytes")
    } else {
        (c"recordings", c"wav")
    };
    let mut handle = conn.lock_handle().await?;
    let db = handle.as_raw_handle().as_ptr();
    // As in `fill_recording`, read-only.
    let blob = open_blob(db, table, column, blob_ref.rowid, false)?;
    // SAFETY: `blob` is open.
    let size = unsafe { ffi::sqlite3_blob_bytes(blob) }.max(0) as u64;
    let res = if size != blob_ref.len {
        Err(err(format!(
            "the recording changed while it was read ({} bytes, now {size})",
            blob_ref.len
        )))
    } else {
        let n = (buf.len() as u64).min(size.saturating_sub(offset)) as usize;
        if n == 0 {
            Ok(0)
        } else {
            // SAFETY: `blob` is open; `buf[..n]` is writable; offset + n <= size < 2^31.
            let rc = unsafe {
                ffi::sqlite3_blob_read(blob, buf.as_mut_ptr().cast(), n as i32, offset as i32)
            };
            if rc == ffi::SQLITE_OK {
                Ok(n)
            } else {
                Err(err(format!("reading the recording blob: {}", message(db))))
            }
        }
    };
    // SAFETY: opened above, closed exactly once.
    unsafe { ffi::sqlite3_blob_close(blob) };
    res
}
