//! Where the tools find the shipped real trials and models (blobs, with the checkpoints beside
//! them that say what they were trained on) at run time, with no path from
//! the build machine: an environment variable when set, else the repository's copy when the
//! tool runs from a checkout's root (as the README's commands do), else the copy embedded in the
//! binary (build.rs), unpacked once into a folder under the system's temporary directory. An
//! installed binary (`cargo install --path host-tools`) therefore runs anywhere.

use std::path::{Path, PathBuf};

mod files {
    include!(concat!(env!("OUT_DIR"), "/shipped_files.rs"));
}

/// Environment variable naming another folder of real trials (eagle-shoal layout or recordings).
pub const DATA_ENV: &str = "SLIPGUARD_DATA";
/// Environment variable naming another models folder (`<dir>/<name>/<name>.bin`).
pub const MODELS_ENV: &str = "SLIPGUARD_MODELS";

/// The real trials: `$SLIPGUARD_DATA`, else `./data/eagle-shoal` in a checkout's root, else the
/// embedded copy.
pub fn data_dir() -> PathBuf {
    resolve(DATA_ENV, "data/eagle-shoal", files::DATA)
}

/// The shipped models folder (`hand-force/hand-force.bin`, …): `$SLIPGUARD_MODELS`, else
/// `./models` in a checkout's root, else the embedded copy.
pub fn models_dir() -> PathBuf {
    resolve(MODELS_ENV, "models", files::MODELS)
}

/// The embedded files, as (path relative to the repository root, bytes): the trials, then the
/// blobs.
pub fn embedded() -> impl Iterator<Item = (&'static str, &'static [u8])> {
    files::DATA.iter().chain(files::MODELS).copied()
}

fn resolve(env: &str, rel: &str, files: &[(&str, &[u8])]) -> PathBuf {
    if let Some(p) = std::env::var_os(env).filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    // A checkout's root: the folder holds this path and the workspace's marker files.
    let here = Path::new(rel);
    if here.is_dir() && Path::new("firmware/core").is_dir() {
        return here.to_path_buf();
    }
    let root = unpacked_root();
    if let Err(e) = unpack(&root, files) {
        eprintln!(
            "slipguard: unpacking the embedded {rel} into {}: {e} (set {env} to a copy instead)",
            root.display()
        );
    }
    root.join(rel)
}

/// `<temp>/slipguard-<version>-<hash of the files>`: a new folder whenever the files change.
fn unpacked_root() -> PathBuf {
    std::env::temp_dir().join(format!(
        "slipguard-{}-{:016x}",
        env!("CARGO_PKG_VERSION"),
        files::HASH
    ))
}

/// Writes every file that is missing or differs, each through a temporary name and a rename,
/// so that concurrent runs never read a half-written file.
fn unpack(root: &Path, files: &[(&str, &[u8])]) -> std::io::Result<()> {
    for (rel, bytes) in files {
        let path = root.join(rel);
        if std::fs::read(&path).is_ok_and(|b| b == *bytes) {
            continue;
        }
        let dir = path.parent().unwrap_or(root);
        std::fs::create_dir_all(dir)?;
        let tmp = dir.join(format!(".{}.{}", std::process::id(), rel.replace('/', "_")));
        std::fs::write(&tmp, bytes)?;
        std::fs::rename(&tmp, &path)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every embedded file is byte for byte the repository's (the source tree is there in a
    /// test run), the set holds the 25 trials and the three shipped blobs, and an unpacked copy
    /// holds the same bytes.
    #[test]
    fn embedded_files_are_the_repositorys_and_unpack() {
        let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let mut n = 0;
        for (rel, bytes) in embedded() {
            assert_eq!(std::fs::read(repo.join(rel)).unwrap(), bytes, "{rel}");
            n += 1;
        }
        let csv = files::DATA
            .iter()
            .filter(|(p, _)| p.ends_with("tactile.csv"))
            .count();
        assert_eq!(csv, 61);
        let blobs: Vec<_> = files::MODELS
            .iter()
            .map(|(p, _)| *p)
            .filter(|p| p.ends_with(".bin"))
            .collect();
        assert_eq!(
            blobs,
            [
                "models/hand-force/hand-force.bin",
                "models/hand-force-40hz/hand-force-40hz.bin",
                "models/suction/suction.bin"
            ]
        );
        assert!(n > 28);
        let root =
            std::env::temp_dir().join(format!("slipguard-unpack-test-{}", std::process::id()));
        unpack(&root, files::MODELS).unwrap();
        // A second unpack over a changed file restores it.
        let p = root.join(files::MODELS[0].0);
        std::fs::write(&p, b"x").unwrap();
        unpack(&root, files::MODELS).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), files::MODELS[0].1);
        std::fs::remove_dir_all(&root).ok();
    }
}
