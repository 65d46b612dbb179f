//! `slipguard eval MODELS...`: one table (paper columns + extra metrics) for every model,
//! float and quantized, on real held-out trials and on simulated force / suction data.
use std::path::{Path, PathBuf};

use anyhow::Context;
use slipguard::plot::plot_prediction;
use slipguard_core::blob::InputUnit;
use slipguard_core::decision::{DecisionConfig, Q15};
use slipguard_learn::checkpoint::{self, Checkpoint};
use slipguard_learn::evaluation::{
    Kind, Row, Sequence, TABLE_HEADER, decide, metrics_of, probabilities, quantize_model,
    row_markdown, sim_force_sequences, sim_suction_sequences,
};

use super::train::load_real;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Checkpoints (.safetensors; a .bin of the same stem is used as its quantized blob),
    /// cross-validation folders (fold*.safetensors) or folders of either.
    #[arg(required = true)]
    pub models: Vec<PathBuf>,
    /// Real data (default: $SLIPGUARD_DATA or <repo>/data/eagle-shoal).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Skip the real trials.
    #[arg(long)]
    pub no_real: bool,
    /// Simulated force trials (16.7 Hz) to evaluate force models on (0 = none).
    #[arg(long, default_value_t = 100)]
    pub sim_force: usize,
    /// Simulated suction trials (71 Hz) to evaluate suction models on (0 = none).
    #[arg(long, default_value_t = 100)]
    pub sim_suction: usize,
    /// Seed of the simulated evaluation sets (training uses 11 and 12).
    #[arg(long, default_value_t = 1000)]
    pub sim_seed: u64,
    /// Write Fig. 8-style PNGs (quantized predictions) into this folder.
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Plots per model and data set.
    #[arg(long, default_value_t = 4)]
    pub plot_count: usize,
    /// Override every model's decision threshold (p(unstable)).
    #[arg(long)]
    pub threshold: Option<f64>,
    /// Override every model's raise_after (hysteresis).
    #[arg(long)]
    pub raise_after: Option<u8>,
    /// Override every model's clear_after.
    #[arg(long)]
    pub clear_after: Option<u8>,
    /// Also write the table (markdown) to this file.
    #[arg(long)]
    pub markdown: Option<PathBuf>,
}

/// A model to evaluate: one checkpoint, or the folds of a cross-validation.
pub struct Group {
    pub name: String,
    pub members: Vec<(Checkpoint, Option<Vec<u8>>)>,
}

fn load_member(p: &Path) -> anyhow::Result<(Checkpoint, Option<Vec<u8>>)> {
    let ck = checkpoint::read(p)?;
    let bin = p.with_extension("bin");
    let blob = if bin.exists() {
        Some(std::fs::read(&bin).with_context(|| format!("reading {}", bin.display()))?)
    } else {
        None
    };
    Ok((ck, blob))
}

fn is_ck(p: &Path) -> bool {
    p.extension().is_some_and(|e| e == "safetensors")
}

fn fold_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
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

/// Resolves the command-line paths into model groups.
pub fn resolve(paths: &[PathBuf]) -> anyhow::Result<Vec<Group>> {
    let mut out = Vec::new();
    let stem = |p: &Path| {
        p.file_stem()
            .map_or("model".into(), |s| s.to_string_lossy().to_string())
    };
    for p in paths {
        anyhow::ensure!(p.exists(), "{} not found", p.display());
        if p.is_file() {
            out.push(Group {
                name: stem(p),
                members: vec![load_member(p)?],
            });
            continue;
        }
        let folds = fold_files(p)?;
        if !folds.is_empty() {
            out.push(Group {
                name: format!("{} (CV)", stem(p)),
                members: folds
                    .iter()
                    .map(|f| load_member(f))
                    .collect::<anyhow::Result<_>>()?,
            });
            continue;
        }
        let mut entries: Vec<PathBuf> = std::fs::read_dir(p)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .collect();
        entries.sort();
        for e in entries {
            if e.is_file() && is_ck(&e) {
                out.push(Group {
                    name: stem(&e),
                    members: vec![load_member(&e)?],
                });
            } else if e.is_dir() {
                let folds = fold_files(&e)?;
                if !folds.is_empty() {
                    out.push(Group {
                        name: format!("{} (CV)", stem(&e)),
                        members: folds
                            .iter()
                            .map(|f| load_member(f))
                            .collect::<anyhow::Result<_>>()?,
                    });
                }
            }
        }
    }
    anyhow::ensure!(!out.is_empty(), "no checkpoints found");
    Ok(out)
}

fn heldout(ck: &Checkpoint) -> Option<Vec<String>> {
    ck.extra
        .get("heldout_trials")
        .map(|s| s.split(',').map(str::to_string).collect())
}

/// Evaluates one model on `data` (`select(member, seq)` picks each member's test sequences),
/// float and quantized; returns the rows and writes plots.
#[allow(clippy::too_many_arguments)]
pub fn eval_group(
    g: &Group,
    data_name: &str,
    data: &[Sequence],
    select: impl Fn(&Checkpoint, &Sequence) -> bool,
    calib: impl Fn(&Checkpoint) -> Vec<Vec<f32>>,
    plots: Option<(&Path, usize)>,
    kinds: &[Kind],
) -> anyhow::Result<Vec<Row>> {
    let mut rows = Vec::new();
    for &kind in kinds {
        let (mut seqs, mut preds) = (Vec::new(), Vec::new());
        for (ck, blob) in &g.members {
            let test: Vec<&Sequence> = data.iter().filter(|s| select(ck, s)).collect();
            if test.is_empty() {
                continue;
            }
            let blob = match (kind, blob) {
                (Kind::Quantized, None) => {
                    let c = calib(ck);
                    let c: Vec<&[f32]> = c.iter().map(Vec::as_slice).collect();
                    quantize_model(&ck.model, &c)?
                }
                (_, Some(b)) => b.clone(),
                (Kind::Float, None) => Vec::new(),
            };
            let p = probabilities(&ck.model, &blob, kind, &test)?;
            let d = DecisionConfig::of(&ck.model.config);
            preds.extend(p.iter().map(|q| decide(d, q)));
            seqs.extend(test);
        }
        if seqs.is_empty() {
            continue;
        }
        if let (Some((dir, n)), Kind::Quantized) = (plots, kind) {
            // Failures first (the interesting ones), then successes.
            let mut idx: Vec<usize> = (0..seqs.len()).collect();
            idx.sort_by_key(|&i| !seqs[i].failure());
            let mut picked: Vec<usize> = idx.iter().copied().take(n.saturating_sub(1)).collect();
            if let Some(&s) = idx.iter().find(|&&i| !seqs[i].failure()) {
                picked.push(s);
            }
            for i in picked {
                let s = seqs[i];
                let slug: String = format!(
                    "{}-{}-{}-c{}",
                    g.name, data_name, s.cs.trial_id, s.cs.channel
                )
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
                let title = format!(
                    "{} ({}) on {} c{}",
                    g.name,
                    kind.name(),
                    s.cs.trial_id,
                    s.cs.channel
                );
                plot_prediction(s, &preds[i], &title, &dir.join(format!("{slug}.png")))?;
            }
        }
        rows.push(Row {
            model: g.name.clone(),
            data: data_name.to_string(),
            kind,
            metrics: metrics_of(&seqs, &preds),
        });
    }
    Ok(rows)
}

/// Held-out description of a group: "fold k: ids" lines.
pub fn heldout_lines(g: &Group) -> Vec<String> {
    g.members
        .iter()
        .filter_map(|(ck, _)| {
            let h = heldout(ck)?;
            Some(format!(
                "{} {}: {}",
                g.name,
                ck.extra.get("fold").map_or("", String::as_str),
                h.join(", ")
            ))
        })
        .collect()
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let mut groups = resolve(&a.models)?;
    for g in &mut groups {
        for (ck, blob) in &mut g.members {
            let c = &mut ck.model.config;
            let before = (c.threshold_q15, c.raise_after, c.clear_after);
            if let Some(t) = a.threshold {
                c.threshold_q15 = Q15::from_f64(t).header_threshold();
            }
            if let Some(r) = a.raise_after {
                c.raise_after = r.max(1);
            }
            if let Some(r) = a.clear_after {
                c.clear_after = r.max(1);
            }
            if before != (c.threshold_q15, c.raise_after, c.clear_after) {
                // The shipped blob carries the old rule: re-quantize with the new one.
                *blob = None;
            }
        }
    }
    let real = if a.no_real {
        Vec::new()
    } else {
        load_real(a.data.as_deref())?.1
    };
    let needs = |u: InputUnit| {
        groups.iter().any(|g| {
            g.members
                .iter()
                .any(|(c, _)| c.model.config.input_unit == u)
        })
    };
    let sim_f = if needs(InputUnit::MilliNewton) {
        sim_force_sequences(a.sim_seed, a.sim_force, 0.3, 16.7)
    } else {
        Vec::new()
    };
    let sim_s = if needs(InputUnit::Counts) {
        sim_suction_sequences(a.sim_seed, a.sim_suction, 0.3)
    } else {
        Vec::new()
    };
    let calib_suction = sim_suction_sequences(999, 16, 0.3);
    let plots = a.plots.as_deref().map(|d| (d, a.plot_count));
    let kinds = [Kind::Float, Kind::Quantized];
    let mut rows = Vec::new();
    let mut notes = Vec::new();
    for g in &groups {
        let unit = g.members[0].0.model.config.input_unit;
        if unit == InputUnit::MilliNewton {
            if !real.is_empty() {
                let cv = g.members.iter().all(|(c, _)| heldout(c).is_some());
                let name = if cv { "real held-out" } else { "real (all)" };
                let calib = |ck: &Checkpoint| -> Vec<Vec<f32>> {
                    let h = heldout(ck).unwrap_or_default();
                    real.iter()
                        .filter(|s| !h.contains(&s.cs.trial_id))
                        .take(64)
                        .map(|s| s.cs.samples.clone())
                        .collect()
                };
                rows.extend(eval_group(
                    g,
                    name,
                    &real,
                    |ck, s| heldout(ck).is_none_or(|h| h.contains(&s.cs.trial_id)),
                    calib,
                    plots,
                    &kinds,
                )?);
                notes.extend(heldout_lines(g));
            }
            if !sim_f.is_empty() {
                // CV groups: fold 0 stands for the recipe on simulated data.
                let g0 = Group {
                    name: g.name.clone(),
                    members: vec![g.members[0].clone()],
                };
                let calib = |ck: &Checkpoint| -> Vec<Vec<f32>> {
                    let h = heldout(ck).unwrap_or_default();
                    real.iter()
                        .filter(|s| !h.contains(&s.cs.trial_id))
                        .take(64)
                        .map(|s| s.cs.samples.clone())
                        .collect()
                };
                rows.extend(eval_group(
                    &g0,
                    &format!("sim force seed {}", a.sim_seed),
                    &sim_f,
                    |_, _| true,
                    calib,
                    plots,
                    &kinds,
                )?);
            }
        } else if !sim_s.is_empty() {
            let calib = |_: &Checkpoint| -> Vec<Vec<f32>> {
                calib_suction.iter().map(|s| s.cs.samples.clone()).collect()
            };
            rows.extend(eval_group(
                g,
                &format!("sim suction 71 Hz seed {}", a.sim_seed),
                &sim_s,
                |_, _| true,
                calib,
                plots,
                &kinds,
            )?);
        }
    }
    let mut text = String::new();
    text.push_str(TABLE_HEADER);
    text.push('\n');
    for r in &rows {
        text.push_str(&row_markdown(r));
        text.push('\n');
    }
    if !notes.is_empty() {
        text.push_str("\nHeld-out trials per fold:\n\n");
        for n in notes {
            text.push_str(&format!("- {n}\n"));
        }
    }
    print!("{text}");
    if let Some(p) = &a.markdown {
        std::fs::write(p, &text).with_context(|| format!("writing {}", p.display()))?;
    }
    if let Some(d) = &a.plots {
        eprintln!("plots in {}", d.display());
    }
    Ok(())
}
