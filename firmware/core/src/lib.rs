//! # slipguard-core
//!
//! The portable inference core of slipguard: the code that runs on the Cortex-M4F next to the
//! fingertip force sensors and, bit for bit, in every host tool. No heap, no panics on data,
//! no `unsafe` outside [`dsp`].
//!
//! The modules follow the data's path from a sensor sample to a flag:
//!
//! ```text
//! raw sample ─▶ sample (Q1.15) ─▶ features (STFT bands, force, d(t), normalised Q3.12)
//!            ─▶ lstm (16x8 quantized cell, h Q0.15, c Q(15-C).C) ─▶ decision (dense → p Q0.15 → flag)
//! ```
//!
//! [`blob`] parses the model blob (formats v1 and v2, `docs/model-format.md`) zero-copy from flash and
//! [`model`] ties the stages together over a per-channel [`model::ChannelState`].
//! Behind the `std` feature, [`float`] is the f32 reference of exactly the same network (what
//! the quantized path is checked against) and [`quantize`] turns float weights into a blob.
//! Host-only speed (many channels at once, the host CPU's SIMD kernels) is the host crate
//! `slipguard-batch`, checked bit for bit against [`model::Model::step`].
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![deny(unsafe_code)]
#![warn(missing_docs)]

#[cfg(target_endian = "big")]
compile_error!("slipguard-core reads model blobs in place and supports little-endian targets only");

pub mod activation;
pub mod blob;
pub mod const_math;
pub mod decision;
pub mod dsp;
pub mod features;
pub mod fixed;
pub mod load_rule;
pub mod lstm;
pub mod model;
pub mod model_ram;
pub mod protocol;
pub mod sample;
pub mod units;

#[cfg(any(test, feature = "std"))]
pub mod float;
#[cfg(any(test, feature = "std"))]
pub mod quantize;

/// Largest LSTM hidden size the static state buffers hold.
pub const MAX_HIDDEN: usize = 128;
/// Largest LSTM input vector (force, d(t) and up to [`features::MAX_BANDS`] STFT bands).
pub const MAX_INPUT: usize = 2 + features::MAX_BANDS;
