//! Ending a QEMU run (`-semihosting-config enable=on,target=native`): [`exit`] with a status that
//! becomes `qemu-system-arm`'s own exit status, and the panic handler (prints, exits
//! [`PANIC_EXIT`], like a failing Rust test).

use cortex_m_semihosting::hprintln;

/// Exit status after a panic.
pub const PANIC_EXIT: i32 = 101;

/// Ends the QEMU run with `code` as its exit status (semihosting SYS_EXIT_EXTENDED, which
/// carries any code; plain SYS_EXIT only tells success from failure).
pub fn exit(code: i32) -> ! {
    const SYS_EXIT_EXTENDED: usize = 0x20;
    const ADP_STOPPED_APPLICATION_EXIT: usize = 0x2_0026;
    let block: [usize; 2] = [ADP_STOPPED_APPLICATION_EXIT, code as usize];
    // SAFETY: a semihosting call with a valid two-word parameter block; QEMU exits here.
    unsafe { cortex_m_semihosting::syscall(SYS_EXIT_EXTENDED, &block) };
    // Only reached when semihosting is not enabled (e.g. on hardware): stop here.
    loop {
        cortex_m::asm::bkpt();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("PANIC: {}", info);
    exit(PANIC_EXIT)
}
