//! Helpers shared by the fuzz targets: an allocation meter (to check that the
//! readers' configured limits bound their memory), a per-process scratch folder,
//! and the checks every reader must pass on arbitrary input.

pub mod fixtures;

use lumiprobe::image::io::Limits;
use lumiprobe::{Error, HdrImage, SdrImage};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

// ---------------------------------------------------------------------------
// Allocation meter: bytes live now and the most live at once since `reset`.

struct Meter;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(n: usize) {
    let now = LIVE.fetch_add(n, Ordering::Relaxed) + n;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

unsafe impl GlobalAlloc for Meter {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = System.alloc(l);
        if !p.is_null() {
            grew(l.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(l);
        if !p.is_null() {
            grew(l.size());
        }
        p
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        let q = System.realloc(p, l, new_size);
        if !q.is_null() {
            LIVE.fetch_sub(l.size(), Ordering::Relaxed);
            grew(new_size);
        }
        q
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        LIVE.fetch_sub(l.size(), Ordering::Relaxed);
        System.dealloc(p, l)
    }
}

#[global_allocator]
static GLOBAL: Meter = Meter;

/// Runs `f` and returns its result with the most bytes that were live at once
/// during the call beyond what was live before it.
pub fn peak_during<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let r = f();
    (r, PEAK.load(Ordering::Relaxed).saturating_sub(base))
}

// ---------------------------------------------------------------------------
// Scratch folder.

/// A folder private to this process (under the system temp dir), created on
/// first use. libFuzzer ends the process without running destructors, so the
/// folders of fuzzing processes that no longer run are removed here instead.
pub fn scratch() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let tmp = std::env::temp_dir();
        if let Ok(rd) = std::fs::read_dir(&tmp) {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                let Some(pid) = name.strip_prefix("lumiprobe-fuzz-") else {
                    continue;
                };
                if pid.parse::<u32>().is_ok() && !Path::new(&format!("/proc/{pid}")).exists() {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
        }
        let d = tmp.join(format!("lumiprobe-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("create scratch folder");
        d
    })
}

// ---------------------------------------------------------------------------
// Reader checks.

/// Limits the image targets decode with: 2^20 pixels (12 MiB as float RGB), small
/// enough that a fuzzing run stays fast and the memory bound below is tight.
pub const IMAGE_LIMITS: Limits = Limits {
    max_pixels: 1 << 20,
};

/// Most memory a reader may hold at once for an input of `len` bytes under
/// `limits`: the float RGB result (12 bytes per pixel); the decoder's own
/// buffers: 16-bit RGBA plus RGB8 in the PNG/JPEG decoder (11 bytes per pixel),
/// scanline and pixel buffers in the others, and for OpenEXR one compressed and
/// one decompressed block (each at most 16 bytes per pixel of the limit, or
/// 16 MiB, see `check_block_sizes` in src/image/io/exr.rs); four times the
/// input; 8 MiB of decoder state.
pub fn image_memory_bound(limits: &Limits, len: usize) -> usize {
    let px = limits.max_pixels as usize;
    let block = (16 * px).max(16 << 20);
    12 * px + (12 * px).max(2 * block) + 4 * len + (8 << 20)
}

/// The error of a failed read must name the file (the crate's promise).
pub fn assert_names_file(e: &Error, name: &Path) {
    let msg = e.to_string();
    let file = name.to_string_lossy();
    assert!(
        msg.contains(file.as_ref()),
        "error does not name {file}: {msg}"
    );
}

/// Width, height and sample count of a decoded image, HDR or 8-bit.
pub trait Decoded {
    /// `(width, height, samples)`.
    fn dims(&self) -> (usize, usize, usize);
}

impl Decoded for HdrImage {
    fn dims(&self) -> (usize, usize, usize) {
        (self.width(), self.height(), self.data().len())
    }
}

impl Decoded for SdrImage {
    fn dims(&self) -> (usize, usize, usize) {
        (self.width(), self.height(), self.data().len())
    }
}

/// Checks an image read: within limits and memory bound on success, naming the
/// file on failure.
pub fn check_image<I: Decoded>(
    name: &Path,
    limits: &Limits,
    len: usize,
    f: impl FnOnce() -> lumiprobe::Result<I>,
) {
    let (r, peak) = peak_during(f);
    let bound = image_memory_bound(limits, len);
    assert!(
        peak <= bound,
        "{}: {peak} bytes live at once, bound {bound}",
        name.display()
    );
    match r {
        Ok(img) => {
            let (w, h, n) = img.dims();
            assert!(w > 0 && h > 0, "empty image accepted");
            assert!((w as u64) * (h as u64) <= limits.max_pixels);
            assert_eq!(n, w * h * 3);
        }
        Err(e) => assert_names_file(&e, name),
    }
}
