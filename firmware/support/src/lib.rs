//! What the slipguard embedded binaries share beyond the portable core and app, each piece
//! behind a feature:
//!
//! - [`model`] (`model-region`): the default model blob in the `.model` section and the MODEL
//!   flash region as read back at run time (board and QEMU application).
//! - [`semihosting`] (`semihosting`): the exit with a status and the panic handler of the QEMU
//!   binaries (application and bench).
//! - [`boot`]: the model line the board and the QEMU application log at boot.
#![no_std]

pub mod boot;
#[cfg(feature = "model-region")]
pub mod model;
#[cfg(feature = "semihosting")]
pub mod semihosting;
