//! slipguard host tools: the data layer (trials, loaders, labelling, simulator,
//! metrics, plots), training (`train`, candle), float checkpoints (`checkpoint`) and
//! evaluation (`evaluation`). Later issues add replay and monitor.
//!
//! Every tool reads one [`trial::Trial`]. Library errors are
//! [`error::DataError`]; the `slipguard` binary adds `anyhow` at its edge.

pub mod baselines;
pub mod checkpoint;
pub mod closed_loop;
pub mod dsp;
pub mod eagle;
pub mod error;
pub mod evaluation;
pub mod labels;
pub mod metrics;
pub mod monitor;
pub mod plot;
pub mod recording;
pub mod replay;
pub mod sim;
pub mod train;
pub mod trial;
pub mod validate;

mod csvtext;

pub use error::{DataError, Result};
pub use trial::{Outcome, Phase, PhaseMarks, SensorKind, Stability, Trial, Unit};

use std::path::Path;

/// Load trials from `path`: a recording file (`.csv` starting with the
/// recording magic line), a folder of recordings, or an eagle-shoal layout
/// (dataset root, `trials/` folder or one trial folder). Trials are annotated
/// with `cfg`; `progress(done, total)` is called as they load.
pub fn load_path(
    path: &Path,
    cfg: &labels::LabelConfig,
    mut progress: impl FnMut(usize, usize),
) -> Result<Vec<Trial>> {
    if path.is_file() {
        let t = recording::read_recording(path, cfg)?;
        progress(1, 1);
        return Ok(vec![t]);
    }
    if !path.exists() {
        return Err(DataError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or folder"),
        ));
    }
    match eagle::trial_dirs(path) {
        Ok(_) => eagle::load_eagle_dataset(path, cfg, progress),
        Err(DataError::NoTrials { .. }) => {
            let rd = std::fs::read_dir(path).map_err(|e| DataError::io(path, e))?;
            let mut files: Vec<_> = rd
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "csv") && recording::is_recording(p))
                .collect();
            files.sort();
            if files.is_empty() {
                return Err(DataError::NoTrials {
                    path: path.to_path_buf(),
                });
            }
            let total = files.len();
            files
                .iter()
                .enumerate()
                .map(|(i, f)| {
                    let t = recording::read_recording(f, cfg);
                    progress(i + 1, total);
                    t
                })
                .collect()
        }
        Err(e) => Err(e),
    }
}
