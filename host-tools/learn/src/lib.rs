//! slipguard learning: the paper's LSTM variants trained with candle ([`train`]) and fine-tuned
//! with the blob's arithmetic ([`qat`]), float
//! checkpoints in safetensors ([`checkpoint`]), the paper's Table I baselines
//! ([`baselines`]), the hand-load rule every hand flag is measured against ([`load_rule`]) and
//! the evaluation of float and quantized models ([`evaluation`]); the training sets built from
//! recorded and simulated trials ([`training_data`]), and the simulated closed loop that both
//! scores a flag source and generates training sequences from the firmware's own path
//! ([`closed_loop`]).
//!
//! Errors are [`error::LearnError`] (candle's and the data layer's wrapped).

#[cfg(feature = "train")]
pub mod baselines;
pub mod checkpoint;
pub mod closed_loop;
pub mod error;
pub mod evaluation;
pub mod hand;
pub mod load_rule;
pub mod product;
#[cfg(feature = "train")]
pub mod qat;
#[cfg(feature = "train")]
pub mod train;
#[cfg(feature = "train")]
pub mod training_data;

pub use error::{LearnError, Result};
