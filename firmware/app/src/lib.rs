//! # slipguard-app
//!
//! The firmware's logic, portable and tested on the host: everything between the ADC's raw
//! scans and the bytes on the UART, except the board itself.
//!
//! ```text
//! ADC scans (raw counts, oversampled) ─▶ frontend: fault detection + anti-alias FIR, ÷R
//!   ─▶ FrameInput (one per model period) ─▶ app: tare, scaling, slipguard-core model per channel,
//!      flags, deadline accounting ─▶ protocol::Frame ─▶ COBS bytes on the UART
//! commands (COBS bytes from the UART) ─▶ upload::Uploader::handle (model uploads into the
//!    flash slots) or app::App::handle ─▶ reply frames (samples frames per the stream mode)
//! ```
//!
//! The embassy firmware (`firmware/src`) and the QEMU build (`firmware/qemu-app`) add only a
//! board layer around [`frontend::Frontend`] and [`app::App`]; [`replay`] drives the same two
//! from a recorded trial on the host, in the same order, so its frames equal the QEMU build's
//! byte for byte.
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]

pub mod app;
pub mod decimate;
pub mod fault;
pub mod frontend;
pub mod profile;
pub mod replay;
pub mod schedule;
pub mod upload;

/// Most channels any profile has (= [`slipguard_core::protocol::MAX_CHANNELS`]).
pub const MAX_CHANNELS: usize = slipguard_core::protocol::MAX_CHANNELS;
