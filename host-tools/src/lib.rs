//! The `slipguard` command line's library half: the firmware's exact path on recorded
//! trials ([`replay`]), the armed-window table ([`armed_table`]), the models named on a command line
//! ([`model_groups`]), the flag-stream monitor ([`monitor`]), the plots ([`plot`]) and the C header's generator ([`c_header`]). Data, simulation and learning live in
//! `slipguard-data`, `slipguard-sim` and `slipguard-learn`; the binary adds `anyhow` at
//! its edge.

pub mod armed_table;
pub mod c_header;
pub mod model_groups;
pub mod monitor;
pub mod plot;
pub mod replay;
