//! The models named on a command line (`slipguard eval`, `slipguard compare`): checkpoints, a
//! cross-validation's fold checkpoints, or folders of either, each with the blob exported
//! beside it when there is one, checked against its sensor profile.

use std::path::{Path, PathBuf};

use slipguard_app::profile::{Profile, ProfileQuery};
use slipguard_learn::checkpoint::{self, Checkpoint};

/// A model to evaluate: one checkpoint, or the folds of a cross-validation; each member with
/// its blob when one is exported beside it.
pub struct Group {
    pub name: String,
    pub members: Vec<(Checkpoint, Option<Vec<u8>>)>,
}

/// Why the named models cannot be loaded.
#[derive(Debug)]
#[non_exhaustive]
pub enum GroupsError {
    /// A path that does not exist.
    NotFound(PathBuf),
    /// A blob without its checkpoint beside it.
    BlobAlone { blob: PathBuf, checkpoint: PathBuf },
    /// A checkpoint that does not read.
    Checkpoint(slipguard_learn::LearnError),
    /// A file or folder that does not read (`what`: "reading <path>", or nothing).
    Io {
        what: Option<PathBuf>,
        source: std::io::Error,
    },
    /// A blob beside a checkpoint that its profile refuses (without `allow_bad`).
    BadBlob { blob: PathBuf, why: String },
    /// No checkpoint under the paths.
    NoCheckpoints,
    /// A checkpoint whose rate and unit no sensor profile runs.
    NoProfile {
        checkpoint: PathBuf,
        why: slipguard_app::profile::ProfileError,
    },
}

impl std::fmt::Display for GroupsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            GroupsError::NotFound(p) => write!(f, "{} not found", p.display()),
            GroupsError::BlobAlone { blob, checkpoint } => write!(
                f,
                "{}: a blob alone cannot be evaluated here (eval compares the float model with its \
                 quantized blob and needs {} beside it); run the blob through the firmware path \
                 with `slipguard replay --model {}` instead",
                blob.display(),
                checkpoint.display(),
                blob.display()
            ),
            GroupsError::Checkpoint(e) => write!(f, "{e}"),
            GroupsError::Io {
                what: Some(p),
                source: _,
            } => write!(f, "reading {}", p.display()),
            GroupsError::Io { what: None, source } => write!(f, "{source}"),
            GroupsError::BadBlob { blob, why } => write!(
                f,
                "{}: {why} (remove or re-export it, or --allow-bad-model to quantize the \
                 checkpoint afresh instead)",
                blob.display()
            ),
            GroupsError::NoCheckpoints => f.write_str("no checkpoints found"),
            GroupsError::NoProfile { checkpoint, why } => {
                write!(f, "{}: {why}", checkpoint.display())
            }
        }
    }
}

impl std::error::Error for GroupsError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            GroupsError::Io {
                what: Some(_),
                source,
            } => Some(source),
            _ => None,
        }
    }
}

/// "reading `path`", with the I/O error as its source.
fn reading(path: &Path) -> impl FnOnce(std::io::Error) -> GroupsError {
    let what = Some(path.to_path_buf());
    move |source| GroupsError::Io { what, source }
}

/// One member: the checkpoint at `p` (or beside the blob `p`) and the blob beside it, checked
/// against the profile of its input unit. A blob the profile refuses stops the load, or with
/// `allow_bad` is reported through `warn` and left out (the checkpoint is then quantized
/// afresh).
fn load_member(
    p: &Path,
    allow_bad: bool,
    warn: &mut dyn FnMut(String),
) -> Result<(Checkpoint, Option<Vec<u8>>), GroupsError> {
    let ck_path = p.with_extension("safetensors");
    if p.extension().is_some_and(|e| e == "bin") && !ck_path.exists() {
        return Err(GroupsError::BlobAlone {
            blob: p.to_path_buf(),
            checkpoint: ck_path,
        });
    }
    let mut ck = checkpoint::read(&ck_path).map_err(GroupsError::Checkpoint)?;
    let bin = ck_path.with_extension("bin");
    let blob = if bin.exists() {
        let b = std::fs::read(&bin).map_err(reading(&bin))?;
        let c = &ck.model.config;
        let profile = Profile::lookup(ProfileQuery::unit_rate(c.input_unit, c.sample_rate_mhz))
            .map_err(|why| GroupsError::NoProfile {
                checkpoint: ck_path.clone(),
                why,
            })?;
        match crate::replay::check_blob(
            &profile,
            slipguard_core::blob::AlignedBlob::new(&b).as_bytes(),
        ) {
            Ok(c) => {
                // The blob's hand rule (format v2, set at export): kept when the checkpoint is
                // quantized afresh with another decision rule (`--threshold` …).
                ck.model.config.hand_rule = c.hand_rule;
                Some(b)
            }
            Err(why) if allow_bad => {
                warn(format!(
                    "eval: warning: {}: {why}; evaluating the checkpoint quantized afresh \
                     instead (--allow-bad-model)",
                    bin.display()
                ));
                None
            }
            Err(why) => return Err(GroupsError::BadBlob { blob: bin, why }),
        }
    } else {
        None
    };
    Ok((ck, blob))
}

fn is_ck(p: &Path) -> bool {
    p.extension().is_some_and(|e| e == "safetensors")
}

/// The `fold*.safetensors` in `dir`, sorted.
fn fold_files(dir: &Path) -> Result<Vec<PathBuf>, GroupsError> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(reading(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            is_ck(p)
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("fold"))
        })
        .collect();
    v.sort();
    Ok(v)
}

/// The model groups of the command-line `paths`: a checkpoint (or blob beside one) is a
/// group; a folder of `fold*` checkpoints is one group "(CV)"; another folder gives a group
/// per checkpoint and per fold folder in it, sorted. `allow_bad` and `warn`: as for one
/// member (a refused blob is reported and left out).
pub fn resolve(
    paths: &[PathBuf],
    allow_bad: bool,
    warn: &mut dyn FnMut(String),
) -> Result<Vec<Group>, GroupsError> {
    let mut out = Vec::new();
    let stem = |p: &Path| {
        p.file_stem()
            .map_or("model".into(), |s| s.to_string_lossy().to_string())
    };
    let folds_group = |name: String, folds: &[PathBuf], warn: &mut dyn FnMut(String)| {
        Ok::<_, GroupsError>(Group {
            name,
            members: folds
                .iter()
                .map(|f| load_member(f, allow_bad, warn))
                .collect::<Result<_, _>>()?,
        })
    };
    for p in paths {
        if !p.exists() {
            return Err(GroupsError::NotFound(p.clone()));
        }
        if p.is_file() {
            out.push(Group {
                name: stem(p),
                members: vec![load_member(p, allow_bad, warn)?],
            });
            continue;
        }
        let folds = fold_files(p)?;
        if !folds.is_empty() {
            out.push(folds_group(format!("{} (CV)", stem(p)), &folds, warn)?);
            continue;
        }
        let mut entries: Vec<PathBuf> = std::fs::read_dir(p)
            .map_err(|source| GroupsError::Io { what: None, source })?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .collect();
        entries.sort();
        for e in entries {
            if e.is_file() && is_ck(&e) {
                out.push(Group {
                    name: stem(&e),
                    members: vec![load_member(&e, allow_bad, warn)?],
                });
            } else if e.is_dir() {
                let folds = fold_files(&e)?;
                if !folds.is_empty() {
                    out.push(folds_group(format!("{} (CV)", stem(&e)), &folds, warn)?);
                }
            }
        }
    }
    if out.is_empty() {
        return Err(GroupsError::NoCheckpoints);
    }
    Ok(out)
}
