//! `slipguard demo`: the README's main command. Runs the shipped quantized blobs through the
//! bit-exact core (`slipguard_core::model::Model`, the firmware's arithmetic): the hand-force
//! model on the real trials and on a seeded simulated force set, the 40 Hz hand-force model on
//! simulated 40 Hz force, the suction model on simulated suction; prints what was run on what,
//! two tables with their counts explained and how to read them, and writes Fig. 8-style plots.
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use slipguard::plot::{flag_verdict, plot_prediction};
use slipguard_core::blob::{AlignedBlob, ModelConfig};
use slipguard_core::model::Model;
use slipguard_core::sample::PAPER_RATE_HZ;
use slipguard_data::labels::LabelConfig;
use slipguard_data::trial::{Outcome, Stability, Trial};
use slipguard_learn::evaluation::{
    Kind, Row, Sequence, TABLE_HEADER, decide, metrics_of, quant_p_q15_many, row_markdown,
    sequences_of, sim_force_sequences, sim_suction_sequences,
};
use slipguard_learn::product::{OnsetRule, armed_window, cut_to_contact};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Real data folder (default: $SLIPGUARD_DATA, else ./data/eagle-shoal in a checkout, else
    /// the copy built into the binary).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Folder with `hand-force/`, `hand-force-40hz/` and `suction/` (default: $SLIPGUARD_MODELS,
    /// else ./models in a checkout, else the copies built into the binary).
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Folder for the plots (PNG files; created if missing).
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Simulated trials per simulated set (count, 1–10 000).
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u32).range(1..=10_000), allow_negative_numbers = true)]
    pub sim_count: u32,
    /// Seed of the simulated sets (integer ≥ 0; the shipped models trained on seeds 11 and 12).
    #[arg(long, default_value_t = 2024, allow_negative_numbers = true)]
    pub sim_seed: u64,
    /// Plots per data set (count, 0–100; failures first, then one success).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(0..=100), allow_negative_numbers = true)]
    pub plot_count: u32,
}

/// Default models folder: [`slipguard_data::shipped::models_dir`].
pub fn default_models_dir() -> PathBuf {
    slipguard_data::shipped::models_dir()
}

/// `path` as a reader would type it: relative to the working directory when inside it, without
/// `..` steps.
fn shown(path: &Path) -> String {
    let abs = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
    let rel = std::env::current_dir()
        .ok()
        .and_then(|cwd| abs.strip_prefix(cwd).ok().map(Path::to_path_buf));
    match rel {
        Some(r) if r.as_os_str().is_empty() => ".".into(),
        Some(r) => r.display().to_string(),
        None => abs.display().to_string(),
    }
}

/// One shipped model.
struct Shipped {
    name: &'static str,
    path: PathBuf,
    bytes: Vec<u8>,
}

impl Shipped {
    fn read(dir: &Path, name: &'static str) -> anyhow::Result<Self> {
        let path = dir.join(name).join(format!("{name}.bin"));
        let bytes = std::fs::read(&path).with_context(|| {
            format!(
                "reading the shipped model {} (pass --models or set $SLIPGUARD_MODELS)",
                path.display()
            )
        })?;
        Ok(Self { name, path, bytes })
    }

    fn with_model<R>(&self, f: impl FnOnce(&Model<'_>) -> R) -> anyhow::Result<R> {
        let aligned = AlignedBlob::new(&self.bytes);
        let model = Model::from_bytes(aligned.as_bytes()).map_err(|e| {
            anyhow::anyhow!("{}: the blob does not parse: {e}", self.path.display())
        })?;
        Ok(f(&model))
    }

    fn config(&self) -> anyhow::Result<ModelConfig> {
        self.with_model(|m| *m.config())
    }
}

/// One line about a model: sensor, rate, variant, size, decision (and the blob's hand rule, when
/// it carries one: format v2).
fn describe(c: &ModelConfig) -> String {
    let sensor = slipguard::plot::sensor_name(c.input_unit);
    let hidden = if c.hidden[1] > 0 {
        format!("{} + {}", c.hidden[0], c.hidden[1])
    } else {
        c.hidden[0].to_string()
    };
    let fused = c.hand_rule.map_or(String::new(), |r| {
        format!("; hand flag fused with the blob's hand-load rule: {r}")
    });
    format!(
        "{sensor}, {} Hz, variant {}, hidden {hidden}; flags at p(unstable) ≥ {:.2} for {} \
         step(s){fused}",
        c.sample_rate_mhz.hz(),
        c.variant,
        c.threshold_q15 as f64 / 32768.0,
        c.raise_after,
    )
}

/// One data set run through one model.
struct Run<'a> {
    model: &'a Shipped,
    /// The data column of the table.
    data: String,
    /// File-name part (letters, digits, `-`).
    slug: &'static str,
    seqs: Vec<Sequence>,
}

/// Runs the set through the model, writes its plots, returns the paper-metrics row and the
/// plots written with their verdicts.
fn run_set(r: &Run<'_>, out: &Path, plots: usize) -> anyhow::Result<(Row, Vec<(PathBuf, String)>)> {
    let (preds, unit) = r.model.with_model(|model| {
        let d = model.decision();
        let samples: Vec<&[f32]> = r.seqs.iter().map(|s| s.cs.samples.as_slice()).collect();
        let preds: Vec<Vec<Stability>> = quant_p_q15_many(model, &samples)
            .iter()
            .map(|p| decide(d, p))
            .collect();
        (preds, model.config().input_unit)
    })?;
    let refs: Vec<&Sequence> = r.seqs.iter().collect();
    // Failures first (the interesting ones), then one success.
    let mut idx: Vec<usize> = (0..refs.len()).collect();
    idx.sort_by_key(|&i| !refs[i].failure());
    let mut picked: Vec<usize> = idx.iter().copied().take(plots.saturating_sub(1)).collect();
    if plots > 0
        && let Some(&s) = idx.iter().find(|&&i| !refs[i].failure())
    {
        picked.push(s);
    }
    let mut written = Vec::new();
    for i in picked {
        let s = refs[i];
        let file = out.join(format!(
            "{}_{}_{}_c{}.png",
            r.model.name,
            r.slug,
            file_part(&s.cs.trial_id),
            s.cs.channel
        ));
        let title = format!(
            "{} (quantized core) on {} {}, channel {}",
            r.model.name, r.slug, s.cs.trial_id, s.cs.channel
        );
        plot_prediction(s, &preds[i], unit, &title, &file)?;
        let flags: Vec<bool> = preds[i].iter().map(|p| p.is_unstable()).collect();
        written.push((
            file,
            flag_verdict(&flags, s.failure(), s.cs.drop_index, s.rate_hz),
        ));
    }
    let row = Row {
        model: r.model.name.to_string(),
        data: r.data.clone(),
        kind: Kind::Quantized,
        metrics: metrics_of(&refs, &preds),
    };
    Ok((row, written))
}

/// A trial id as part of a file name: letters, digits, `-` and `_` kept, anything else `-`.
fn file_part(id: &str) -> String {
    id.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '-'
            }
        })
        .collect()
}

/// The reference row of a set: a detector that never flags, scored by the same metrics.
fn never_flags_row(data: &str, seqs: &[Sequence]) -> String {
    let refs: Vec<&Sequence> = seqs.iter().collect();
    let preds: Vec<Vec<Stability>> = seqs
        .iter()
        .map(|s| vec![Stability::Stable; s.cs.samples.len()])
        .collect();
    let row = Row {
        model: "(reference: never flags)".into(),
        data: data.to_string(),
        kind: Kind::Quantized,
        metrics: metrics_of(&refs, &preds),
    };
    row_markdown(&row).replacen("| quantized |", "| - |", 1)
}

/// Why the real trials' counts differ between the two tables, counted from the data.
struct Counts {
    trials: usize,
    failures: usize,
    /// Trials with an armed window (the grasps of table 1), and the failures among them.
    grasps: usize,
    failed_grasps: usize,
    /// Trials without one, and why.
    skipped: Vec<String>,
    /// Contact channels of the grasps (the channel rows of table 1).
    channels: usize,
    /// Labelled channel sequences before the cut to the firmware's contact onset.
    sequences: usize,
    /// Dropped by the cut: no onset by the core's rule in the labelled window.
    no_onset: usize,
    /// Dropped by the cut: the onset at or after the drop.
    onset_after_drop: usize,
    /// Failing channels whose contact ends before the drop: after the cut their sequence
    /// holds no drop, so the paper's metrics count them neither as failures nor as successes.
    contact_ends_before_drop: usize,
}

fn count_real(trials: &[Trial], rule: &OnsetRule, labelled: &[Sequence]) -> Counts {
    let cfg = LabelConfig::default();
    let (mut grasps, mut failed_grasps, mut channels, mut skipped) = (0, 0, 0, Vec::new());
    for t in trials {
        match armed_window(t, &cfg) {
            Ok(Some(_)) => {
                grasps += 1;
                failed_grasps += usize::from(t.outcome == Outcome::Failure);
                channels += t.contact.iter().filter(|&&c| c).count();
            }
            Ok(None) => skipped.push(format!("{} (no contact channel)", t.id)),
            Err(e) => skipped.push(format!("{} ({e})", t.id)),
        }
    }
    let (mut no_onset, mut onset_after_drop, mut contact_ends_before_drop) = (0, 0, 0);
    for s in labelled {
        match rule.first_contact(&s.cs.samples) {
            None => no_onset += 1,
            Some((on, _)) if s.cs.drop_index.is_some_and(|d| on >= d) => onset_after_drop += 1,
            Some((_, off)) if s.failure() && s.cs.drop_index.is_none_or(|d| d >= off) => {
                contact_ends_before_drop += 1
            }
            Some(_) => {}
        }
    }
    Counts {
        trials: trials.len(),
        failures: trials
            .iter()
            .filter(|t| t.outcome == Outcome::Failure)
            .count(),
        grasps,
        failed_grasps,
        skipped,
        channels,
        sequences: labelled.len(),
        no_onset,
        onset_after_drop,
        contact_ends_before_drop,
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let models = a.models.clone().unwrap_or_else(default_models_dir);
    let hand = Shipped::read(&models, "hand-force")?;
    let hand40 = Shipped::read(&models, "hand-force-40hz")?;
    let suction = Shipped::read(&models, "suction")?;
    let (data_path, trials) = super::load_real_trials(a.data.as_deref())?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let (seed, count) = (a.sim_seed, a.sim_count as usize);

    let hand_cfg = hand.config()?;
    let hand40_cfg = hand40.config()?;
    let suction_cfg = suction.config()?;
    let rule = OnsetRule::of(&hand_cfg);
    let labelled = sequences_of(&trials, &LabelConfig::default());
    let counts = count_real(&trials, &rule, &labelled);
    let real = cut_to_contact(labelled, &rule);
    let armed = slipguard::armed_table::rows_for_blob("hand-force", &hand.bytes, &trials, true)?;

    let rate40 = hand40_cfg.sample_rate_mhz.hz_f32();
    let runs = [
        Run {
            model: &hand,
            data: format!("real, {} trials", counts.grasps),
            slug: "real",
            seqs: real,
        },
        Run {
            model: &hand,
            data: format!("simulated force {PAPER_RATE_HZ} Hz, {count} trials"),
            slug: "simforce",
            seqs: cut_to_contact(sim_force_sequences(seed, count, 0.3, PAPER_RATE_HZ), &rule),
        },
        Run {
            model: &hand40,
            data: format!("simulated force {rate40} Hz, {count} trials"),
            slug: "simforce40hz",
            seqs: cut_to_contact(
                sim_force_sequences(seed, count, 0.3, rate40),
                &OnsetRule::of(&hand40_cfg),
            ),
        },
        Run {
            model: &suction,
            data: format!("simulated suction 71 Hz, {count} trials"),
            slug: "simsuction",
            seqs: sim_suction_sequences(seed, count, 0.3),
        },
    ];
    let mut rows = Vec::new();
    let mut plots = Vec::new();
    for r in &runs {
        let (row, written) = run_set(r, &a.out, a.plot_count as usize)?;
        rows.push((row, never_flags_row(&r.data, &r.seqs)));
        plots.extend(written);
    }

    println!(
        "slipguard demo: the shipped quantized models, run through the bit-exact fixed-point core \
         (the firmware's arithmetic, on this computer), on real and simulated grasps.\n"
    );
    println!("Models ({}):", shown(&models));
    for (m, c) in [
        (&hand, &hand_cfg),
        (&hand40, &hand40_cfg),
        (&suction, &suction_cfg),
    ] {
        println!("  {:<16} {}: {}", m.name, shown(&m.path), describe(c));
    }
    println!("Data:");
    println!(
        "  real       {}: {} trials of the Eagle Shoal set ({} failures), {PAPER_RATE_HZ} Hz, \
         fingertip force in mN",
        shown(&data_path),
        counts.trials,
        counts.failures
    );
    println!(
        "  simulated  slipguard-sim, seed {seed} ({count} trials per set, 30 % failures; the \
         shipped models trained on seeds 11 and 12, not this one)"
    );

    println!("\n1. As a grip controller uses the flags (hand-force on the real trials):\n");
    println!(
        "   One grasp = one trial; its hand flag is the firmware's decision over the channels in \
         contact."
    );
    println!(
        "   {} trials -> {} grasps: {} without an armed window ({}).",
        counts.trials,
        counts.grasps,
        counts.skipped.len(),
        if counts.skipped.is_empty() {
            "none".to_string()
        } else {
            counts.skipped.join(", ")
        }
    );
    if let Some(r) = &hand_cfg.hand_rule {
        println!(
            "   hand (fused): this blob carries a hand rule (format v2), so its hand flag is the \
             model's hand decision fused with the hand-load rule, as the firmware computes it: \
             {r}. The `load rule` row is the rule alone (fraction and window picked leave one \
             trial out). These rows are in-sample for the model; held out, the model alone does \
             not beat the rule and the fused flag matches the rule's detections and false alarms \
             with a longer median lead (docs/results.md)."
        );
    }
    println!(
        "   The {} grasps have {} contact channels: the `channel` row scores each one's own flag.\n",
        counts.grasps, counts.channels
    );
    println!("{}", slipguard::armed_table::ARMED_HEADER);
    println!("{armed}");
    // `armed` already holds the hand-load rule's rows beside the model's (the baseline every
    // learned flag is read against, `slipguard::armed_table::rows_for_blob`), on the same trials.
    println!("{}", slipguard::armed_table::ARMED_NOTE);
    println!(
        "\n   Reading it: good is every failure detected ({f}/{f} at hand level) with a long lead \
         (more time to tighten the grip), and no false-alarm grasp (0/{s}). A detector that always \
         flags scores {f}/{f} and {s}/{s}; one that never flags 0/{f} and 0/{s}. The intervals are \
         95 % bootstrap intervals over trials.",
        f = counts.failed_grasps,
        s = counts.grasps - counts.failed_grasps,
    );

    println!("\n2. The paper's metrics, per channel sequence (each model on each data set):\n");
    let cut = counts.no_onset + counts.onset_after_drop;
    println!(
        "   Real trials: the {} contact channels give {} labelled sequences (160 steps from the \
         grasp). Each is cut to where the firmware runs the channel's model, from its contact \
         onset to its contact end: {} left out ({} with no onset by the core's contact rule, {} \
         with the onset at or after the drop), and {} failing channels lose contact before the \
         object drops, so their cut sequence holds no drop and counts neither as a failure nor \
         as a success. Hence {} sequences in the real rows.\n",
        counts.channels,
        counts.sequences,
        cut,
        counts.no_onset,
        counts.onset_after_drop,
        counts.contact_ends_before_drop,
        counts.sequences - cut - counts.contact_ends_before_drop,
    );
    println!("{TABLE_HEADER}");
    for (row, reference) in &rows {
        println!("{}", row_markdown(row));
        println!("{reference}");
    }
    println!(
        "\n   Reading it: success rate = steps where the flag equals the label (the reference row \
         shows what never flagging scores: the share of stable steps); ahead-drop = failing \
         sequences flagged before the drop (good: 100 %); false alarms = succeeding sequences \
         with any flag (good: 0 %); lead median = drop - first flag; event precision / recall = \
         flag events that match a labelled unstable event, and labelled events caught."
    );
    println!(
        "   hand-force was trained on these real trials, so its real rows are in-sample; its \
         held-out figures are in models/hand-force/README.md and docs/results.md. The simulated \
         sets are new to every model."
    );

    println!(
        "\nPlots ({}, {} files; the flag is 1 = unstable as on the wire, the title says the \
         outcome):",
        shown(&a.out),
        plots.len()
    );
    for (p, verdict) in &plots {
        println!("  {}  {verdict}", shown(p));
    }
    println!("\ndone in {:.1} s", t0.elapsed().as_secs_f64());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_have_no_commas_or_spaces() {
        assert_eq!(file_part("Cheez_100,814 top"), "Cheez_100-814-top");
    }

    #[test]
    fn default_models_dir_has_no_parent_steps() {
        let d = default_models_dir();
        assert!(d.ends_with("models"));
        assert!(!d.components().any(|c| c == std::path::Component::ParentDir));
    }
}
