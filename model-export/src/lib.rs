//! # slipguard-export
//!
//! Turns trained float LSTM weights (PyTorch/safetensors, ONNX, Keras 3) into the firmware's
//! quantized model blob (format v1, or v2 with a hand rule; `docs/model-format.md`), with calibration on recorded data,
//! a report of what quantization cost, `inspect`/`verify` for existing blobs, and `upload` of a
//! blob to the board over its serial link.
//! See `docs/export.md`.

pub mod calib;
pub mod error;
pub mod hand;
pub mod import;
pub mod inspect;
pub mod pipeline;
pub mod report;
pub mod run;
pub mod settings;
pub mod upload;
pub mod write;

pub use error::{ExportError, Result};
