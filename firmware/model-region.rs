// Shared by the firmware (`src/main.rs`) and its QEMU build (`qemu-app/src/main.rs`), which
// `include!` it: the default model blob in the `.model` section and the MODEL region as read
// back at run time. `build-model.rs` chooses the blob and writes the linker fragment.

#[repr(C, align(4))]
struct Aligned<T>(T);

const BLOB_BYTES: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/model.bin"));

/// The default model blob (chosen at build time, see `build-model.rs`), placed at the start of
/// the MODEL region by `model.x`. The application reads the region, not this constant.
#[used]
#[unsafe(link_section = ".model")]
static MODEL_BLOB: Aligned<[u8; BLOB_BYTES.len()]> =
    Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/model.bin")));

unsafe extern "C" {
    static __smodel: u8;
    static __emodel: u8;
}

/// The whole MODEL region as the CPU sees it: whatever was flashed or loaded there (the blob
/// may have been re-flashed on its own), not the compile-time contents of `MODEL_BLOB`.
fn model_region() -> &'static [u8] {
    let start = &raw const __smodel;
    let end = &raw const __emodel;
    let len = (end as usize).saturating_sub(start as usize);
    // SAFETY: the linker script defines both symbols as the bounds of the MODEL region, which is
    // memory-mapped flash (or the emulator's ROM), readable and unchanged for the whole run.
    unsafe { core::slice::from_raw_parts(start, len) }
}
