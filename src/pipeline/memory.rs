//! How many frames `run` computes at once: one per worker thread, unless
//! their working memory would pass a limit (`--memory-limit`; by default
//! three quarters of the memory free when the run starts, within the
//! process's cgroup limit). Each frame in flight holds a few full-size
//! images of its own (the linearised frame, the base estimate, the output,
//! region labels), so a panorama of `w x h` pixels takes about
//! [`bytes_per_pixel`] `x w x h` bytes per frame; the probes add their own
//! pixels, once per probe whatever the number of frames using them. With
//! fewer frames in flight than threads, the idle threads work inside the
//! frames (resampling, compression), so a large panorama is not slower per
//! frame, only less parallel across frames.

use super::Method;

/// Bytes per pixel of a frame in flight, by method: the peak resident memory of
/// one frame at 7776x3888 on one thread (kitchen, `/usr/bin/time -v`: fusion
/// and flow 1.58 GiB, warp 1.07 GiB) less the program's base, over its pixels
/// (51.5 and 33.6), with a margin (docs/speed.md, "Frames in flight by
/// memory").
pub fn bytes_per_pixel(method: Method) -> u64 {
    match method {
        Method::Warp => 40,
        Method::Flow | Method::Hybrid | Method::Fusion => 56,
    }
}

/// Bytes probes of `px` pixels in all take once loaded and prepared (float RGB
/// and an 8-bit tone-mapped copy); where a run `matches` features against
/// them (the warp and hybrid methods, as a method or as fusion's base), also
/// their float display copy, which the warp method keeps for probes up to 4M
/// pixels (all of them with the Reinhard tone mapping): counted here at every
/// size, an overestimate for larger probes.
pub fn probe_bytes(matches: bool, px: u64) -> u64 {
    if matches {
        28 * px
    } else {
        16 * px
    }
}

/// Resident memory of the program itself before any frame (code, OpenCV,
/// the scene's tables).
const BASE_BYTES: u64 = 128 << 20;

/// What `run` decided.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Frames computed at once.
    pub workers: usize,
    /// Estimated peak: the base, the probes and `workers` frames.
    pub peak: u64,
    /// The limit it kept to.
    pub limit: u64,
    /// Why fewer frames than threads run at once, or why the limit cannot be
    /// kept, in the user's words.
    pub note: Option<String>,
}

fn gib(b: u64) -> String {
    format!("{:.1} GiB", b as f64 / (1u64 << 30) as f64)
}

/// Frames in flight for `threads` worker threads and `frames` frames to
/// compute of `frame_px` pixels each with `method`, with `probes_px` the
/// pixels of the probes the run keeps loaded, matched against when `matches`
/// ([`probe_bytes`]), under `limit` bytes.
pub fn plan(
    method: Method,
    frame_px: u64,
    probes_px: u64,
    matches: bool,
    threads: usize,
    frames: usize,
    limit: u64,
) -> Plan {
    let per_frame = bytes_per_pixel(method).saturating_mul(frame_px);
    let fixed = BASE_BYTES.saturating_add(probe_bytes(matches, probes_px));
    let wanted = threads.clamp(1, frames.max(1));
    let fits = limit.saturating_sub(fixed) / per_frame.max(1);
    let workers = usize::try_from(fits).unwrap_or(usize::MAX).clamp(1, wanted);
    let peak = fixed.saturating_add(per_frame.saturating_mul(workers as u64));
    let note = if peak > limit {
        Some(format!(
            "one frame of this size needs about {} with the {} method (probes \
             included), more than the memory limit of {}: frames are computed one \
             at a time and the run may still run out of memory; give a smaller \
             --size or a larger --memory-limit",
            gib(peak),
            method.name(),
            gib(limit)
        ))
    } else if workers < wanted {
        Some(format!(
            "{workers} frame(s) computed at a time instead of {wanted}, to stay \
             within the memory limit of {} (about {} per frame); the other threads \
             help inside each frame (--memory-limit to change it)",
            gib(limit),
            gib(per_frame)
        ))
    } else {
        None
    };
    Plan {
        workers,
        peak,
        limit,
        note,
    }
}

/// The default limit: three quarters of the memory free now (`MemAvailable`
/// in `/proc/meminfo`), and no more than the room left under the process's
/// cgroup (v2) limits ([`cgroup_room`]); 4 GiB where neither can be read.
pub fn default_limit() -> u64 {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let available = meminfo.as_deref().and_then(mem_available);
    let cgroup = cgroup_room();
    match (available, cgroup) {
        (Some(a), Some(c)) => a.min(c) / 4 * 3,
        (Some(a), None) => a / 4 * 3,
        (None, Some(c)) => c / 4 * 3,
        (None, None) => 4 << 30,
    }
}

/// `MemAvailable` of a `/proc/meminfo` text, in bytes.
fn mem_available(meminfo: &str) -> Option<u64> {
    meminfo.lines().find_map(|l| {
        let rest = l.strip_prefix("MemAvailable:")?;
        let kb: u64 = rest.trim().trim_end_matches("kB").trim().parse().ok()?;
        kb.checked_mul(1024)
    })
}

/// The least room under the memory limits of the process's cgroup (v2, from
/// `/proc/self/cgroup`) and its ancestors: `memory.max` less what is in use
/// (`memory.current` without the page cache the kernel can drop,
/// `inactive_file` of `memory.stat`). `None` when no limit is set or none
/// can be read.
fn cgroup_room() -> Option<u64> {
    let own = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    let rel = own.lines().find_map(|l| l.strip_prefix("0::"))?.trim();
    let root = std::path::Path::new("/sys/fs/cgroup");
    let mut dir = root.join(rel.trim_start_matches('/'));
    let mut room: Option<u64> = None;
    loop {
        let read = |f: &str| std::fs::read_to_string(dir.join(f)).ok();
        if let Some(max) = read("memory.max").and_then(|m| m.trim().parse::<u64>().ok()) {
            let current: u64 = read("memory.current")
                .and_then(|c| c.trim().parse().ok())
                .unwrap_or(0);
            let cache = read("memory.stat")
                .as_deref()
                .and_then(inactive_file)
                .unwrap_or(0);
            let here = max.saturating_sub(current.saturating_sub(cache));
            room = Some(room.map_or(here, |r| r.min(here)));
        }
        if dir == root || !dir.pop() || !dir.starts_with(root) {
            break;
        }
    }
    room
}

/// `inactive_file` of a cgroup's `memory.stat` text, in bytes.
fn inactive_file(stat: &str) -> Option<u64> {
    stat.lines()
        .find_map(|l| l.strip_prefix("inactive_file ")?.trim().parse().ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    const GIB: u64 = 1 << 30;

    #[test]
    fn every_thread_gets_a_frame_when_the_frames_fit() {
        let p = plan(
            Method::Fusion,
            512 * 256,
            5 * 512 * 256,
            false,
            8,
            20,
            4 * GIB,
        );
        assert_eq!(p.workers, 8);
        assert!(p.note.is_none());
        // Never more workers than frames.
        assert_eq!(
            plan(Method::Fusion, 512 * 256, 0, false, 8, 3, 4 * GIB).workers,
            3
        );
    }

    #[test]
    fn probes_matched_against_count_their_display_copy() {
        let px = 7776 * 3888;
        let probes = 5 * 2048 * 1024;
        let plain = plan(Method::Fusion, px, probes, false, 8, 20, 64 * GIB);
        let matched = plan(Method::Fusion, px, probes, true, 8, 20, 64 * GIB);
        assert_eq!(matched.peak - plain.peak, 12 * probes);
    }

    #[test]
    fn large_panoramas_run_fewer_frames_at_once_and_say_so() {
        let px = 7776 * 3888;
        let p = plan(Method::Fusion, px, 5 * 512 * 256, false, 8, 20, 4 * GIB);
        assert!(p.workers >= 1 && p.workers < 8, "{p:?}");
        assert!(p.peak <= 4 * GIB, "{p:?}");
        assert!(p.note.as_deref().unwrap().contains("memory limit"));
        // One more frame would not have fitted.
        let one_more = p.peak + bytes_per_pixel(Method::Fusion) * px as u64;
        assert!(one_more > 4 * GIB);
    }

    #[test]
    fn a_frame_larger_than_the_limit_runs_alone_with_a_warning() {
        let px = 30_000 * 15_000;
        let p = plan(Method::Warp, px, 0, true, 2, 20, 4 * GIB);
        assert_eq!(p.workers, 1);
        assert!(p.peak > p.limit);
        assert!(p.note.as_deref().unwrap().contains("--size"));
    }

    #[test]
    fn mem_available_is_read_in_bytes() {
        let text = "MemTotal:       24000000 kB\nMemFree:  100 kB\nMemAvailable:   20000000 kB\n";
        assert_eq!(mem_available(text), Some(20_000_000 * 1024));
        assert_eq!(mem_available("MemTotal: 1 kB\n"), None);
        let stat = "anon 10\nfile 20\ninactive_file 4096\nactive_file 5\n";
        assert_eq!(inactive_file(stat), Some(4096));
        assert_eq!(inactive_file("anon 1\n"), None);
    }
}
