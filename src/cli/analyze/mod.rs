//! `springbench analyze DIR`: offline analysis of a recording set, one
//! command module: [`args`] (flags and their checks), [`table`] (the result
//! as a table), [`diagnose`] (`--diagnose`: model diagnostics, level series).
pub mod args;
pub mod diagnose;
pub mod table;

pub use args::{check_flags, parse_method, AnalyzeArgs};
pub use table::table;

use crate::identify::{analyze_owned, AnalyzeOptions};
use crate::recording::{RecordingSet, RecordingSetFiles};

pub fn run(args: AnalyzeArgs) -> Result<(), String> {
    keep_freed_memory();
    let method = parse_method(&args.method)?;
    check_flags(&args)?;
    let set = RecordingSet::read_dir(&args.dir).map_err(|e| e.to_string())?;
    if args.diagnose {
        return diagnose::run(&set, &args);
    }
    let opts = AnalyzeOptions {
        method,
        order: args.order,
    };
    // The set is given away: its raw channels are freed as soon as the
    // analysis has read them (lower peak memory, fewer fresh pages).
    let report = analyze_owned(set, &opts).map_err(|e| e.to_string())?;
    if args.json {
        let text = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
        println!("{text}");
    } else {
        print!("{}", table(&report));
    }
    Ok(())
}

/// A one-shot process: memory freed by one stage is reused by the next
/// instead of going back to the kernel. glibc hands blocks above 128 kB to
/// mmap and unmaps them on free, so each multi-megabyte FFT buffer, spectrum
/// and column of the analysis came back as fresh pages; a page fault costs
/// about 2.5 us on the 2-core machine, 0.6 ms per MB (docs/performance.md).
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes glibc's allocation thresholds; called
    // before the analysis allocates (the process has one thread here).
    unsafe {
        // 32 MiB is glibc's upper limit for the mmap threshold.
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        // One arena for every thread: rayon's workers (where the decoding
        // and the analysis run) otherwise allocate from arenas of their own,
        // outside the huge-page heap below, and fault their ~60 MB in 4 kB
        // pages: 14 300 page faults a run instead of 1 800 (decision 0091).
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
    huge_page_heap();
}

/// Grows the heap by 96 MiB up front, advises the kernel to back it with
/// transparent huge pages, and returns it to malloc's free list: the
/// analysis's channels, FFT buffers and spectra (~50 MB) are then carved
/// from it and fault in 2 MiB at a time (~9 000 page faults of 4 kB cost
/// ~20 ms on the 2-core machine; decision 0026). The pages are only
/// touched when used.
fn huge_page_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc/free of blocks this function owns; madvise only on
    // whole 2 MiB pages inside them (advice: an error leaves 4 kB pages).
    unsafe {
        const HUGE: usize = 2 << 20;
        // Below the mmap threshold set above, so the blocks come from the heap.
        let blocks: Vec<*mut libc::c_void> = (0..4).map(|_| libc::malloc(24 << 20)).collect();
        for &p in blocks.iter().filter(|p| !p.is_null()) {
            let start = p as usize;
            let (a, b) = (
                start.next_multiple_of(HUGE),
                (start + (24 << 20)) / HUGE * HUGE,
            );
            if b > a {
                libc::madvise(a as *mut libc::c_void, b - a, libc::MADV_HUGEPAGE);
            }
        }
        for p in blocks {
            libc::free(p);
        }
    }
}
