//! `slipguard compare RUNS...`: the learned hand flag against the hand-load rule on the same
//! held-out grasps, over repeated cross-validation (one CV folder per training seed): every
//! figure as mean and range over the seeds, and per grasp, paired (lead difference per
//! failure, false alarm per success). With `--seeds` it trains the CV runs first.
use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use slipguard_data::Trial;
use slipguard_data::armed::{ArmedGrasp, ArmedMetrics};
use slipguard_data::labels::LabelConfig;
use slipguard_learn::product;

use super::load_real_trials;
use slipguard::model_groups::{Group, resolve};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Cross-validation folders (fold*.safetensors from `slipguard train --cv K`), one per
    /// training seed.
    pub runs: Vec<PathBuf>,
    /// Real data (default: $SLIPGUARD_DATA or <repo>/data/eagle-shoal).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Train the CV runs first, one per seed (comma-separated), into `--out`/seed<S>, with the
    /// `slipguard train` options after `--` (`--cv K` among them; `--seed`, `--out` and
    /// `--name` are set here). A seed whose folder already holds folds is not trained again.
    #[arg(long, value_delimiter = ',', requires = "out")]
    pub seeds: Vec<u64>,
    /// Folder of the trained runs (with `--seeds`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write the tables (markdown) to this file too.
    #[arg(long)]
    pub markdown: Option<PathBuf>,
    /// Write the figures as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Guard of the fused decision: the model's flag counts while the hand load is below this
    /// fraction of its recent peak (fixed beforehand, not tuned; the strict fraction and the
    /// window are the rule's, picked per fold on its training trials). 1 = no guard.
    #[arg(long, default_value_t = 0.8, value_parser = super::check::unit)]
    pub guard: f64,
    /// `slipguard train` options (after `--`).
    #[arg(last = true)]
    pub train_args: Vec<String>,
}

/// One seed's held-out grasps: the model's hand flag and the rule's, by trial.
struct SeedRun {
    name: String,
    model: Vec<ArmedGrasp>,
    rule: Vec<ArmedGrasp>,
    rule_picks: String,
    /// The fused decision: the fold's rule OR the model's flag under the fixed guard.
    fused: Vec<ArmedGrasp>,
    /// The fused decision with strict fraction, guard and window picked per fold on its
    /// training trials (the fold's model in-sample there).
    tuned: Vec<ArmedGrasp>,
    tuned_picks: Vec<String>,
}

fn train_seeds(a: &Args) -> anyhow::Result<Vec<PathBuf>> {
    let Some(out) = &a.out else {
        return Ok(Vec::new());
    };
    let exe = std::env::current_exe().context("finding the slipguard executable")?;
    let mut dirs = Vec::new();
    for &seed in &a.seeds {
        let dir = out.join(format!("seed{seed}"));
        let folds = dir.join("m");
        let done = folds.is_dir()
            && std::fs::read_dir(&folds)?.any(|e| {
                e.ok()
                    .is_some_and(|e| e.file_name().to_string_lossy().starts_with("fold"))
            });
        if !done {
            eprintln!("compare: training seed {seed} into {}", dir.display());
            let status = std::process::Command::new(&exe)
                .arg("train")
                .args(&a.train_args)
                .args(["--seed", &seed.to_string(), "--name", "m", "--out"])
                .arg(&dir)
                .status()
                .context("starting slipguard train")?;
            anyhow::ensure!(status.success(), "slipguard train (seed {seed}) failed");
        }
        dirs.push(folds);
    }
    Ok(dirs)
}

fn seed_run(
    g: &Group,
    trials: &[Trial],
    real: &[slipguard_learn::evaluation::Sequence],
    guard: f64,
) -> anyhow::Result<SeedRun> {
    use slipguard_learn::load_rule;
    let cfg = LabelConfig::default();
    let config = &g.members[0].0.model.config;
    let all: Vec<&Trial> = trials.iter().collect();
    let loads = load_rule::load_runs(
        &all,
        &slipguard_core::sample::InputScale::of(config),
        &slipguard_core::decision::ContactConfig::of(config),
        &cfg,
    )?;
    let folds: Vec<Vec<String>> = g
        .members
        .iter()
        .filter_map(|(ck, _)| ck.heldout_trials())
        .collect();
    let rule = slipguard_learn::load_rule::beside_model(trials, config, Some(&folds))?;
    let mut model = Vec::new();
    let mut fused = Vec::new();
    let (mut tuned, mut tuned_picks) = (Vec::new(), Vec::new());
    for (ck, blob) in &g.members {
        let h = ck.heldout_trials().ok_or_else(|| {
            anyhow::anyhow!(
                "{}: a checkpoint without held-out trials; compare takes cross-validation folders \
                 (slipguard train --cv K)",
                g.name
            )
        })?;
        let bytes = slipguard_learn::evaluation::blob_or_quantized(ck, blob.as_ref(), real)?;
        let aligned = slipguard_core::blob::AlignedBlob::new(&bytes);
        let m = slipguard_core::model::Model::from_bytes(aligned.as_bytes())
            .map_err(|e| anyhow::anyhow!("{}: the model blob does not parse: {e}", g.name))?;
        // Every trial: the held-out ones are scored, the fold's training trials (in-sample for
        // this model) pick the fused decision.
        let runs = product::windowed_runs(&m, &all, &cfg)?;
        let mut pairs = Vec::new();
        let mut test = Vec::new();
        for w in &runs {
            let Some(l) = loads.iter().find(|l| l.trial == w.trial) else {
                continue;
            };
            if h.contains(&w.trial) {
                if let Some(t) = all.iter().find(|t| t.id == w.trial)
                    && let Some(sc) = product::score(t, &w.run, &cfg)?
                {
                    model.push(sc.hand);
                }
                test.push((l, w.run.model_flag.as_slice()));
            } else {
                pairs.push((l, w.run.model_flag.as_slice()));
            }
        }
        // The fold's own rule (picked on its training trials) with the fixed guard.
        if let Some((_, r)) = rule
            .per_fold
            .iter()
            .find(|(ids, _)| ids.iter().any(|i| h.contains(i)))
        {
            let f = slipguard_core::decision::FusedHand {
                strict: *r,
                guard_q15: load_rule::fused(0.0, guard, 0.0, 1.0).guard_q15,
            };
            fused.extend(test.iter().map(|(l, m)| l.fused_grasp(m, &f)));
        }
        if let Some(f) = load_rule::pick_fused(&pairs) {
            tuned.extend(test.iter().map(|(l, m)| l.fused_grasp(m, &f)));
            tuned_picks.push(load_rule::fused_name(&f));
        }
    }
    Ok(SeedRun {
        name: g.name.clone(),
        model,
        rule: rule.grasps,
        rule_picks: rule.picks,
        fused,
        tuned,
        tuned_picks,
    })
}

/// Mean and range of `v` as "mean (lo–hi)" with `prec` decimals.
fn mean_range(v: &[f64], prec: usize) -> String {
    if v.is_empty() {
        return "-".into();
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if lo == hi {
        format!("{mean:.prec$}")
    } else {
        format!("{mean:.prec$} ({lo:.prec$}–{hi:.prec$})")
    }
}

/// The figures of one detector over the seeds: one row.
fn summary_row(name: &str, per_seed: &[ArmedMetrics]) -> (String, serde_json::Value) {
    let f = |g: &dyn Fn(&ArmedMetrics) -> f64| per_seed.iter().map(g).collect::<Vec<f64>>();
    let failures = per_seed.first().map_or(0, |m| m.failures);
    let successes = per_seed.first().map_or(0, |m| m.successes);
    let det = f(&|m| m.detected as f64);
    let d300 = f(&|m| m.detected_with_lead(300.0) as f64);
    let lead = per_seed
        .iter()
        .filter_map(ArmedMetrics::lead_median_ms)
        .collect::<Vec<f64>>();
    let fa = f(&|m| m.false_alarm_grasps as f64);
    let fam = f(&|m| m.false_alarms_per_min().unwrap_or(0.0));
    let row = format!(
        "| {name} | {} | {}/{failures} | {}/{failures} | {} ms | {}/{successes} | {} |",
        per_seed.len(),
        mean_range(&det, 2),
        mean_range(&d300, 2),
        mean_range(&lead, 0),
        mean_range(&fa, 2),
        mean_range(&fam, 2),
    );
    let json = serde_json::json!({
        "detector": name,
        "seeds": per_seed.len(),
        "failures": failures,
        "successes": successes,
        "detected": det,
        "detected_300ms": d300,
        "lead_median_ms": lead,
        "false_alarm_grasps": fa,
        "false_alarms_per_min": fam,
    });
    (row, json)
}

pub fn run(mut a: Args) -> anyhow::Result<()> {
    let trained = train_seeds(&a)?;
    a.runs.extend(trained);
    anyhow::ensure!(
        !a.runs.is_empty(),
        "no runs: pass CV folders (one per training seed) or --seeds 1,2,3 --out DIR -- <train options>"
    );
    let mut groups = resolve(&a.runs, false, &mut |w| eprintln!("{w}"))?;
    if groups.len() == a.runs.len() {
        // One group per folder: named by its path, which tells the seeds apart.
        for (g, p) in groups.iter_mut().zip(&a.runs) {
            g.name = p.display().to_string();
        }
    }
    let (_, all) = load_real_trials(a.data.as_deref())?;
    let refs: Vec<&Trial> = all.iter().collect();
    let (keep, skipped) = product::scoreable(&refs, &LabelConfig::default())?;
    for e in &skipped {
        eprintln!("compare: skipped {e}");
    }
    let trials: Vec<Trial> = keep.into_iter().cloned().collect();
    let real = product::sequences_from_contact(&trials);
    let mut seeds = Vec::new();
    for g in &groups {
        seeds.push(seed_run(g, &trials, &real, a.guard)?);
        eprintln!("compare: {} scored", g.name);
    }
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Hand flag against the hand-load rule, cross-validation by trial, {} training seed{} \
         ({}), held-out grasps in the armed window (hand level). Figures: mean over the seeds, \
         range in brackets (no range: the same on every seed).\n",
        seeds.len(),
        if seeds.len() == 1 { "" } else { "s" },
        seeds
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(
        md,
        "| detector | seeds | detected | ≥ 300 ms ahead | lead median | false-alarm grasps | false alarms / armed min |\n|---|---:|---|---|---|---|---|"
    );
    let model_m: Vec<ArmedMetrics> = seeds.iter().map(|s| ArmedMetrics::of(&s.model)).collect();
    let rule_m: Vec<ArmedMetrics> = seeds.iter().map(|s| ArmedMetrics::of(&s.rule)).collect();
    let (r1, j1) = summary_row("model (hand flag)", &model_m);
    let (r2, j2) = summary_row("load rule", &rule_m);
    let fused_m: Vec<ArmedMetrics> = seeds.iter().map(|s| ArmedMetrics::of(&s.fused)).collect();
    let (r3, j3) = summary_row(
        &format!("fused: rule OR (model flag AND load < {:.2}·peak)", a.guard),
        &fused_m,
    );
    let tuned_m: Vec<ArmedMetrics> = seeds.iter().map(|s| ArmedMetrics::of(&s.tuned)).collect();
    let (r4, j4) = summary_row("fused, all three parameters picked per fold", &tuned_m);
    let _ = writeln!(md, "{r1}\n{r2}\n{r3}\n{r4}");
    let _ = writeln!(
        md,
        "\nLoad rule parameters, picked on each fold's training trials: {}.",
        seeds.first().map_or("", |s| s.rule_picks.as_str())
    );
    let _ = writeln!(
        md,
        "\nFused: the fold's rule at its picked fraction and window, OR the model's hand flag \
         while the hand load is below {:.2} of the same peak (`slipguard_core::decision::FusedHand`; \
         the guard fixed beforehand). The last row picks strict fraction, guard and window per fold \
         on its training trials, where the fold's model is in-sample:\n",
        a.guard
    );
    for s in &seeds {
        let _ = writeln!(md, "- {}: {}", s.name, s.tuned_picks.join("; "));
    }
    // Paired per grasp.
    let mut ids: Vec<(&str, bool)> = seeds
        .first()
        .map(|s| {
            s.rule
                .iter()
                .map(|g| (g.trial.as_str(), g.failure))
                .collect()
        })
        .unwrap_or_default();
    ids.sort();
    let find = |v: &[ArmedGrasp], id: &str| v.iter().find(|g| g.trial == id).cloned();
    let fmt_lead = |l: Option<f64>| l.map_or("missed".into(), |l| format!("{l:.0}"));
    let _ = writeln!(
        md,
        "\nPer failure: lead (ms) of the rule and of the model on each seed, and the model's lead \
         minus the rule's (a miss counts as lead 0).\n"
    );
    let _ = writeln!(
        md,
        "| failure | rule | model ({}) | model − rule (mean, range) | fused |\n|---|---:|---|---|---|",
        seeds
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>()
            .join(" / ")
    );
    let mut per_failure = Vec::new();
    for &(id, failure) in ids.iter().filter(|x| x.1) {
        let _ = failure;
        let rule = seeds
            .first()
            .and_then(|s| find(&s.rule, id))
            .and_then(|g| g.lead_ms());
        let leads: Vec<Option<f64>> = seeds
            .iter()
            .map(|s| find(&s.model, id).and_then(|g| g.lead_ms()))
            .collect();
        let fused: Vec<Option<f64>> = seeds
            .iter()
            .map(|s| find(&s.fused, id).and_then(|g| g.lead_ms()))
            .collect();
        let diff: Vec<f64> = leads
            .iter()
            .map(|l| l.unwrap_or(0.0) - rule.unwrap_or(0.0))
            .collect();
        let _ = writeln!(
            md,
            "| {id} | {} | {} | {} | {} |",
            fmt_lead(rule),
            leads
                .iter()
                .map(|l| fmt_lead(*l))
                .collect::<Vec<_>>()
                .join(" / "),
            mean_range(&diff, 0),
            fused
                .iter()
                .map(|l| fmt_lead(*l))
                .collect::<Vec<_>>()
                .join(" / "),
        );
        per_failure.push(serde_json::json!({
            "trial": id, "rule_lead_ms": rule, "model_lead_ms": leads, "model_minus_rule_ms": diff,
            "fused_lead_ms": fused,
        }));
    }
    let _ = writeln!(
        md,
        "\nPer success: a false alarm (any hand flag in the armed window) of the rule and of the \
         model on each seed.\n"
    );
    let _ = writeln!(
        md,
        "| success | rule | model ({}) | fused |\n|---|---|---|---|",
        seeds
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>()
            .join(" / ")
    );
    let mut per_success = Vec::new();
    let yn = |b: bool| if b { "alarm" } else { "—" };
    for &(id, _) in ids.iter().filter(|x| !x.1) {
        let rule = seeds
            .first()
            .and_then(|s| find(&s.rule, id))
            .is_some_and(|g| g.alarms() > 0);
        let model: Vec<bool> = seeds
            .iter()
            .map(|s| find(&s.model, id).is_some_and(|g| g.alarms() > 0))
            .collect();
        let fused: Vec<bool> = seeds
            .iter()
            .map(|s| find(&s.fused, id).is_some_and(|g| g.alarms() > 0))
            .collect();
        let _ = writeln!(
            md,
            "| {id} | {} | {} | {} |",
            yn(rule),
            model.iter().map(|&b| yn(b)).collect::<Vec<_>>().join(" / "),
            fused.iter().map(|&b| yn(b)).collect::<Vec<_>>().join(" / ")
        );
        per_success.push(serde_json::json!({
            "trial": id, "rule_alarm": rule, "model_alarm": model, "fused_alarm": fused,
        }));
    }
    if !skipped.is_empty() {
        let _ = writeln!(md, "\nSkipped (not scored in the armed window):\n");
        for e in &skipped {
            let _ = writeln!(md, "- {e}");
        }
    }
    print!("{md}");
    if let Some(p) = &a.markdown {
        std::fs::write(p, &md).with_context(|| format!("writing {}", p.display()))?;
    }
    if let Some(p) = &a.json {
        let v = serde_json::json!({
            "summary": [j1, j2, j3, j4],
            "per_failure": per_failure,
            "per_success": per_success,
            "skipped": skipped.iter().map(ToString::to_string).collect::<Vec<_>>(),
        });
        let text = serde_json::to_string_pretty(&v).context("encoding the figures as JSON")?;
        std::fs::write(p, text + "\n").with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_range() {
        assert_eq!(mean_range(&[5.0, 6.0, 7.0], 2), "6.00 (5.00–7.00)");
        assert_eq!(mean_range(&[4.0, 4.0], 0), "4");
        assert_eq!(mean_range(&[], 0), "-");
    }
}
