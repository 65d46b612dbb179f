//! The MODEL flash region: the default model blob placed at its start and the region as the CPU
//! sees it. `build.rs` chooses the blob and writes the `model.x` linker fragment that places the
//! `.model` section there and defines `__smodel`/`__emodel`.

#[repr(C, align(4))]
struct Aligned<T>(T);

const BLOB_BYTES: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/model.bin"));

/// Bytes of the default model blob built into the image (the application reads the region, not
/// this blob: a blob flashed there on its own is what runs).
pub const DEFAULT_BLOB_LEN: usize = BLOB_BYTES.len();

/// The default model blob (chosen at build time, see `build.rs`), placed at the start of the
/// MODEL region by `model.x`, which also names it in `EXTERN` so that it is always linked.
#[used]
#[unsafe(no_mangle)]
#[unsafe(link_section = ".model")]
static SLIPGUARD_DEFAULT_MODEL: Aligned<[u8; DEFAULT_BLOB_LEN]> =
    Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/model.bin")));

unsafe extern "C" {
    static __smodel: u8;
    static __emodel: u8;
}

/// The whole MODEL region as the CPU sees it: whatever was flashed or loaded there (the blob
/// may have been re-flashed on its own), not the compile-time contents of the default blob.
pub fn region() -> &'static [u8] {
    let start = &raw const __smodel;
    let end = &raw const __emodel;
    let len = (end as usize).saturating_sub(start as usize);
    // SAFETY: the linker script defines both symbols as the bounds of the MODEL region, which is
    // memory-mapped flash (or the emulator's ROM), readable and unchanged for the whole run.
    unsafe { core::slice::from_raw_parts(start, len) }
}
