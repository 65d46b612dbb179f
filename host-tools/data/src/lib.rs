//! slipguard grasp data: the trial type every tool reads ([`trial::Trial`]), our
//! recording format ([`recording`]), the eagle-shoal loader ([`eagle`]), the paper's
//! labels ([`labels`]), the evaluation metrics ([`metrics`]) and the model settings keys of
//! checkpoints and exporter settings ([`checkpoint_keys`]). No ML, plotting or
//! serial dependency: the exporter stands on this crate.
//!
//! Errors are [`error::DataError`].

pub mod armed;
pub mod checkpoint_keys;
pub mod eagle;
pub mod error;
pub mod labels;
pub mod metrics;
pub mod pipe;
pub mod recording;
pub mod resample;
pub mod shipped;
pub mod trial;

mod csvtext;

pub use error::{DataError, Result};
pub use trial::{Outcome, Phase, PhaseMarks, SensorKind, Stability, Trial, Unit};

use std::path::Path;

/// Load trials from `path`: a recording file (`.csv` starting with the
/// recording magic line), a folder of recordings, or an eagle-shoal layout
/// (dataset root, `trials/` folder or one trial folder). Trials are annotated
/// with `cfg` (its step counts are at the paper's 16.7 Hz and keep their durations at each
/// recording's rate, [`labels::LabelConfig::scaled_to`]); `progress(done, total)` is called as
/// they load. A folder whose recordings differ in rate, unit or sensor is refused, naming the
/// first file that differs and both values: a data set trains one model at one rate.
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
            let mut trials: Vec<Trial> = Vec::with_capacity(total);
            for (i, f) in files.iter().enumerate() {
                let t = recording::read_recording(f, cfg)?;
                if let Some(first) = trials.first()
                    && let Some(message) = trial::same_rate_and_unit(first, &files[0], &t)
                {
                    return Err(DataError::Shape {
                        path: f.clone(),
                        message,
                    });
                }
                trials.push(t);
                progress(i + 1, total);
            }
            Ok(trials)
        }
        Err(e) => Err(e),
    }
}
