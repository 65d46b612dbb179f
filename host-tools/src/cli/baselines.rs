//! `slipguard baselines [PATH]`: the paper's Table I baselines (NB, KNN k = 3, SVM) and an
//! "all stable" floor, cross-validated by trial, scored with the shared metrics.
use std::path::PathBuf;

use anyhow::Context;
use clap::ValueEnum;
use serde::Serialize;
use slipguard_data::labels::{LabelConfig, LabelStatus, label_annotated};
use slipguard_data::metrics::EventConfig;
use slipguard_data::{eagle, load_path};
use slipguard_learn::baselines::{
    Classifier, CvResult, DEFAULT_FULL_SCALE_MN, FeatureSet, FoldPlan, PAPER_TABLE_I, PaperRow,
    ReportRow, SvmSettings, build_sequences, cross_validate, make_folds, trial_outcomes,
};

use super::progress::bar;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Features {
    /// All 16 channels at a step (the paper's Table I).
    Multi,
    /// One contact channel: force, d(t), 10 STFT bands (the LSTM's input).
    Single,
    /// Both.
    Both,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Model {
    /// Predict stable everywhere (reference floor).
    Stable,
    /// Gaussian Naive Bayes.
    Nb,
    /// k nearest neighbours (--k).
    Knn,
    /// RBF SVM (--svm-c, --svm-gamma, --svm-max-train).
    Svm,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset root, trial folder, recording or folder of recordings
    /// (default: $SLIPGUARD_DATA or <repo>/data/eagle-shoal).
    pub path: Option<PathBuf>,
    /// Feature set.
    #[arg(long, value_enum, default_value = "both")]
    pub features: Features,
    /// Models, comma separated.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "stable,nb,knn,svm"
    )]
    pub models: Vec<Model>,
    /// Folds by trial; 0 = leave one trial out, else 2 to the number of trials.
    #[arg(long, default_value_t = 0)]
    pub folds: usize,
    /// Only these trial ids (repeatable).
    #[arg(long = "trial")]
    pub trials: Vec<String>,
    /// Neighbours of KNN.
    #[arg(long, default_value_t = 3, value_parser = super::check::usize_in!(1..))]
    pub k: usize,
    /// SVM soft margin C.
    #[arg(long, default_value_t = 1.0, value_parser = super::check::positive)]
    pub svm_c: f64,
    /// SVM RBF gamma (default 1 / number of features, on standardised features).
    #[arg(long, value_parser = super::check::positive)]
    pub svm_gamma: Option<f64>,
    /// SVM training steps per fold at most (evenly spaced); 0 = all.
    #[arg(long, default_value_t = 4000, value_parser = super::check::usize_in!(1..))]
    pub svm_max_train: usize,
    /// Raw force (mN) that maps to 1.0 in the single-channel features.
    #[arg(long, default_value_t = DEFAULT_FULL_SCALE_MN, value_parser = clap::value_parser!(i32).range(1..))]
    pub full_scale: i32,
    /// Steps before the drop from which steps are unstable.
    #[arg(long, default_value_t = 20)]
    pub lead: usize,
    /// Sequence length from grasp start.
    #[arg(long, default_value_t = 160, value_parser = super::check::usize_in!(1..=1_000_000))]
    pub seq_len: usize,
    /// Print the report as JSON on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct Report<'a> {
    command: String,
    data: String,
    fold_plan: FoldPlan,
    folds: Vec<Vec<String>>,
    skipped_trials: Vec<String>,
    label_lead_steps: usize,
    sequence_len: usize,
    full_scale_mn: i32,
    rows: Vec<ReportRow>,
    paper_table_i: &'a [PaperRow],
}

fn pct(v: Option<f64>) -> String {
    v.map_or("n/a".into(), |v| format!("{:.2}%", 100.0 * v))
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let cfg = LabelConfig {
        unstable_lead_steps: a.lead,
        sequence_len: a.seq_len,
        ..LabelConfig::default()
    };
    cfg.check().map_err(anyhow::Error::msg)?;
    anyhow::ensure!(a.k >= 1, "--k must be at least 1");
    anyhow::ensure!(a.full_scale > 0, "--full-scale must be positive");
    let path = a.path.clone().unwrap_or_else(eagle::default_data_dir);
    let pb = bar(0, "loading");
    let mut trials = load_path(&path, &cfg, |i, n| {
        pb.set_length(n as u64);
        pb.set_position(i as u64);
    })
    .with_context(|| format!("loading {}", path.display()))?;
    pb.finish_and_clear();
    if !a.trials.is_empty() {
        for id in &a.trials {
            anyhow::ensure!(
                trials.iter().any(|t| &t.id == id),
                "no trial `{id}` in {}",
                path.display()
            );
        }
        trials.retain(|t| a.trials.contains(&t.id));
    }
    let labels: Vec<_> = trials.iter().map(|t| label_annotated(t, &cfg)).collect();
    let skipped: Vec<String> = labels
        .iter()
        .filter(|l| l.status != LabelStatus::Labelled)
        .map(|l| l.id.clone())
        .collect();

    let sets: &[FeatureSet] = match a.features {
        Features::Multi => &[FeatureSet::MultiChannel],
        Features::Single => &[FeatureSet::SingleChannel],
        Features::Both => &[FeatureSet::MultiChannel, FeatureSet::SingleChannel],
    };
    let mut models = a.models.clone();
    models.dedup();
    let classifiers: Vec<Classifier> = models
        .iter()
        .map(|m| match m {
            Model::Stable => Classifier::AllStable,
            Model::Nb => Classifier::NaiveBayes,
            Model::Knn => Classifier::Knn { k: a.k },
            Model::Svm => Classifier::Svm(SvmSettings {
                c: a.svm_c,
                gamma: a.svm_gamma,
                max_train: a.svm_max_train,
                ..SvmSettings::default()
            }),
        })
        .collect();
    let plan = if a.folds == 0 {
        FoldPlan::LeaveOneTrialOut
    } else {
        FoldPlan::KFold(a.folds)
    };
    let ev = EventConfig::default();

    // The folds come from the labelled trials, so they are the same for both feature sets
    // (a trial without contact channels has no single-channel sequence and is then simply
    // not predicted in that set).
    let all_multi = build_sequences(&trials, &labels, FeatureSet::MultiChannel, a.full_scale);
    anyhow::ensure!(!all_multi.is_empty(), "no labelled trials to evaluate");
    let outcomes = trial_outcomes(&all_multi);
    anyhow::ensure!(
        a.folds != 1 && a.folds <= outcomes.len(),
        "--folds {}: 0 (leave one trial out) or 2 to the number of labelled trials ({})",
        a.folds,
        outcomes.len()
    );
    let folds = make_folds(&outcomes, plan);

    let mut results: Vec<CvResult> = Vec::new();
    for &set in sets {
        let seqs = match set {
            FeatureSet::MultiChannel => all_multi.clone(),
            FeatureSet::SingleChannel => build_sequences(&trials, &labels, set, a.full_scale),
        };
        if seqs.is_empty() {
            eprintln!("no {} sequences (no contact channels); skipped", set.name());
            continue;
        }
        for c in &classifiers {
            let pb = bar(folds.len() as u64, &format!("{} {}", c.name(), set.name()));
            let r = cross_validate(&seqs, set, c, &folds, ev, |i, _| pb.set_position(i as u64))
                .with_context(|| format!("{} on {} features", c.name(), set.name()))?;
            pb.finish_and_clear();
            results.push(r);
        }
    }

    let command = std::iter::once("slipguard".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ");
    if a.json {
        let report = Report {
            command,
            data: path.display().to_string(),
            fold_plan: plan,
            folds,
            skipped_trials: skipped,
            label_lead_steps: cfg.unstable_lead_steps,
            sequence_len: cfg.sequence_len,
            full_scale_mn: a.full_scale,
            rows: results.iter().map(ReportRow::of).collect(),
            paper_table_i: &PAPER_TABLE_I,
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }

    println!(
        "Table I baselines on {} ({} trials, {} labelled), {}",
        path.display(),
        trials.len(),
        all_multi.len(),
        match plan {
            FoldPlan::LeaveOneTrialOut => "leave one trial out".to_string(),
            FoldPlan::KFold(k) => format!("{k}-fold by trial"),
        }
    );
    println!(
        "{:<15} {:<11} {:>8} {:>14} {:>8} {:>8} {:>13} {:>9} {:>9} {:>9}  {:>6} {:>6} {:>6} {:>6} {:>6}",
        "features",
        "model",
        "success",
        "ahead-drop",
        "paper",
        "paper",
        "false alarm",
        "lead ms",
        "event P",
        "event R",
        "TP",
        "FP",
        "TN",
        "FN",
        "s"
    );
    println!(
        "{:<15} {:<11} {:>8} {:>14} {:>8} {:>8} {:>13} {:>9} {:>9} {:>9}",
        "", "", "rate", "rate (n)", "success", "ahead", "(n)", "median", "", ""
    );
    for r in &results {
        let m = &r.metrics;
        let paper = (r.features == FeatureSet::MultiChannel)
            .then(|| r.classifier.paper_row())
            .flatten();
        println!(
            "{:<15} {:<11} {:>8} {:>14} {:>8} {:>8} {:>13} {:>9} {:>9} {:>9}  {:>6} {:>6} {:>6} {:>6} {:>6.1}",
            r.features.name(),
            r.classifier.name(),
            pct(m.success_rate),
            format!("{} ({})", pct(m.ahead_drop_rate), m.failure_sequences),
            paper.map_or("-".into(), |p| format!("{:.2}%", p.success_rate_pct)),
            paper.map_or("-".into(), |p| format!("{:.2}%", p.ahead_drop_pct)),
            format!("{} ({})", pct(m.false_alarm_rate), m.success_sequences),
            m.lead_time
                .map_or("n/a".into(), |s| format!("{:.0}", s.median)),
            pct(m.event_precision),
            pct(m.event_recall),
            m.confusion.tp,
            m.confusion.fp,
            m.confusion.tn,
            m.confusion.fn_,
            r.seconds
        );
    }
    let lstm = PAPER_TABLE_I[3];
    println!(
        "{:<15} {:<11} {:>8} {:>14} {:>7.2}% {:>7.2}%   (paper's LSTM; ours: slipguard eval)",
        "16-channel", "LSTM", "-", "-", lstm.success_rate_pct, lstm.ahead_drop_pct
    );
    println!();
    println!(
        "held-out trials per fold (a fold's trials are predicted by a model trained on all other trials):"
    );
    for (i, f) in folds.iter().enumerate() {
        println!("  fold {:>2}: {}", i + 1, f.join(", "));
    }
    if !skipped.is_empty() {
        println!("skipped (no labels): {}", skipped.join(", "));
    }
    println!(
        "labels: unstable from {} steps before the drop, {} steps from grasp start; \
         single-channel features: force/{} mN, d(t), 10 STFT bands (core float path); \
         SVM: C {}, gamma {}, at most {} training steps per fold",
        cfg.unstable_lead_steps,
        cfg.sequence_len,
        a.full_scale,
        a.svm_c,
        a.svm_gamma
            .map_or("1/n_features".to_string(), |g| g.to_string()),
        a.svm_max_train
    );
    Ok(())
}
