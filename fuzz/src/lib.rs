//! Shared pieces of the panoman fuzz targets: the allocation cap and scratch files.
//!
//! Every target links this crate, whose global allocator aborts the process (a libFuzzer
//! crash, input saved) on any single allocation above [`MAX_ALLOC`]: a header that lies
//! about its counts must be rejected before it allocates, whatever sanitizer (or none) the
//! target was built with. libFuzzer's own `-malloc_limit_mb` needs a sanitizer's allocator
//! hooks; this cap does not.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::path::PathBuf;

/// The largest single allocation a reader may make (64 MiB).
pub const MAX_ALLOC: usize = 64 << 20;

/// The global allocator of the fuzz targets: [`System`] with the [`MAX_ALLOC`] cap.
pub struct CappedAlloc;

fn over_cap(size: usize) -> bool {
    size > MAX_ALLOC
}

#[cold]
fn abort_over_cap(size: usize) -> ! {
    // No allocation here: a fixed buffer and a raw write.
    let mut buf = [0u8; 96];
    let mut w = &mut buf[..];
    let _ = write!(
        w,
        "panoman-fuzz: allocation of {size} bytes exceeds the 64 MiB cap\n"
    );
    let n = 96 - w.len();
    let _ = std::io::stderr().write_all(&buf[..n]);
    std::process::abort();
}

// SAFETY: forwards to `System` unchanged; only refuses (aborts on) oversized requests.
unsafe impl GlobalAlloc for CappedAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if over_cap(layout.size()) {
            abort_over_cap(layout.size());
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if over_cap(layout.size()) {
            abort_over_cap(layout.size());
        }
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if over_cap(new_size) {
            abort_over_cap(new_size);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOC: CappedAlloc = CappedAlloc;

/// A per-process scratch folder for the file-based readers: in `/dev/shm` when it exists
/// (no disk I/O), else the system temp folder.
pub fn scratch_dir() -> PathBuf {
    let base = if std::path::Path::new("/dev/shm").is_dir() {
        PathBuf::from("/dev/shm")
    } else {
        std::env::temp_dir()
    };
    let dir = base.join(format!("panoman-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("create the fuzz scratch folder");
    dir
}

/// Writes `bytes` to `name` in the [`scratch_dir`] (created once per process) and returns
/// its path.
pub fn scratch_file(name: &str, bytes: &[u8]) -> PathBuf {
    static DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    let path = DIR.get_or_init(scratch_dir).join(name);
    std::fs::write(&path, bytes).expect("write a fuzz scratch file");
    path
}

/// Asserts that an error message names `path` (every reader's errors must say which file).
pub fn assert_names(err: &dyn std::fmt::Display, path: &std::path::Path) {
    let msg = err.to_string();
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    assert!(
        msg.contains(&name),
        "error does not name the file {path:?}: {msg}"
    );
}
