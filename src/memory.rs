//! Handing freed memory back to the operating system between the parts of a bake in parts.
//!
//! A bake in parts (`--max-memory`) frees each part before the next is decoded. glibc's
//! allocator keeps freed heap memory resident (below its trim threshold, and in the middle of
//! the heap), and after a few parts of different sizes it cannot reuse all of it, so the peak
//! resident size of the process creeps past the budget the parts were planned for (measured on
//! the 1 GB hero cache at `--max-memory 384M`: 1.08x the budget; with the trim, 0.95x).
//! [`release_freed`] asks glibc to return every free page (`malloc_trim(0)`, which since glibc
//! 2.8 also releases whole free pages inside the heap); elsewhere it does nothing.
#![allow(unsafe_code)]

/// Return the allocator's free pages to the operating system (glibc `malloc_trim(0)`); a no-op
/// on other C libraries.
pub(crate) fn release_freed() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn malloc_trim(pad: usize) -> std::ffi::c_int;
        }
        // SAFETY: `malloc_trim` takes a plain integer, touches only the allocator's own state
        // (under its locks) and is safe to call at any time from any thread.
        unsafe {
            malloc_trim(0);
        }
    }
}
