//! # slipguard-export
//!
//! Turns trained float LSTM weights (PyTorch/safetensors, ONNX, Keras 3) into the firmware's
//! quantized model blob (format v1, `docs/model-format.md`), with calibration on recorded data,
//! a report of what quantization cost, and `inspect`/`verify` for existing blobs.
//! See `docs/export.md`.

pub mod calib;
pub mod error;
pub mod import;
pub mod inspect;
pub mod pipeline;
pub mod report;
pub mod run;
pub mod settings;
pub mod write;

pub use error::{ExportError, Result};
