//! The `bake` binary: the command line of the library ([`bake::cli::main`]: parses arguments,
//! calls the library, prints, maps errors to exit codes).

fn main() {
    fixed_mmap_threshold();
    bake::cli::main();
}

/// Gives every heap block of 1 MiB or more back to the system when it is freed (glibc).
///
/// glibc's malloc serves blocks above its mmap threshold by `mmap`, but each time such a block is
/// freed it raises the threshold to that block's size (up to 32 MiB), after which blocks of that
/// size come from the heap and stay in the process once freed. A bake allocates and frees blocks
/// of tens of MiB (a light-map band's horizons and texels, an env-map shard's rays): the
/// 200,000-instance preview's peak was 1.68 GB with the moving threshold and 1.58 GB with this
/// one, at the same wall time (docs/PERFORMANCE.md, "The default's peak at 200,000 instances").
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn fixed_mmap_threshold() {
    // SAFETY: `mallopt` only sets a malloc parameter; it runs before any other thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn fixed_mmap_threshold() {}
