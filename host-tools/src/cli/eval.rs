//! `slipguard eval MODELS...`: one table (paper columns + extra metrics) for every model,
//! float and quantized, on real held-out trials and on simulated force / suction data.
use std::path::{Path, PathBuf};

use anyhow::Context;
use slipguard::armed_table::{
    ARMED_HEADER, ARMED_NOTE, Product, RULE_NOTE, armed_row, fused_note, hand_level,
};
use slipguard::model_groups::{Group, resolve};
use slipguard::plot::plot_prediction;
use slipguard_app::profile::ProfileId;
use slipguard_core::blob::InputUnit;
use slipguard_core::decision::{DecisionConfig, Q15};
use slipguard_core::sample::{PAPER_RATE_HZ, PAPER_RATE_MHZ};
use slipguard_core::units::Millihertz;
use slipguard_learn::checkpoint::Checkpoint;
use slipguard_learn::evaluation::{
    Kind, Row, Sequence, TABLE_HEADER, decide, metrics_of, probabilities, quantize_model,
    row_markdown, sim_force_sequences, sim_suction_sequences,
};

use slipguard_data::Trial;
use slipguard_data::armed::{ArmedGrasp, ArmedReport};
use slipguard_data::labels::LabelConfig;
use slipguard_learn::evaluation::sequences_of;
use slipguard_learn::product::{self, CurvePoint, OnsetRule};

use super::load_real_trials;

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
    /// Override every model's decision threshold (p(unstable)), 0 < threshold < 1.
    #[arg(long, value_parser = super::check::open_unit)]
    pub threshold: Option<f64>,
    /// Override every model's raise_after (hysteresis), 1…255.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..))]
    pub raise_after: Option<u8>,
    /// Override every model's clear_after, 1…255.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..))]
    pub clear_after: Option<u8>,
    /// Write the figures as JSON: `paper.success_rate`, `paper.ahead_drop`, `armed.grasps`,
    /// `armed.failures`, `armed.detected`, `armed.detected_rate`, `armed.lead_median_ms`,
    /// `armed.false_alarm_grasps`, `armed.false_alarm_grasp_rate`, `armed.false_alarms_per_min`
    /// (rates in 0…1), each real-data figure with a `…_ci` [lo, hi] 95 % bootstrap interval
    /// over trials, and `armed_channel.*` for the per-channel flags. One object for one model,
    /// an array for several.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Also write the table (markdown) to this file.
    #[arg(long)]
    pub markdown: Option<PathBuf>,
    /// A checkpoint's `.bin` that the firmware would refuse (does not parse, over the build's
    /// bounds, rate or unit not the profile's): warn and quantize the checkpoint afresh instead
    /// of stopping.
    #[arg(long)]
    pub allow_bad_model: bool,
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
                let unit = g.members[0].0.model.config.input_unit;
                plot_prediction(s, &preds[i], unit, &title, &dir.join(format!("{slug}.png")))?;
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

/// The paper's rows of a hand-level model (float and quantized): one sequence per grasp from
/// the grasp start (`slipguard_learn::hand::paper_sequences`), each member on its held-out
/// trials (all trials without folds).
fn hand_paper_rows(
    g: &Group,
    trials: &[Trial],
    cv: bool,
    kinds: &[Kind],
) -> anyhow::Result<Vec<Row>> {
    let mut rows = Vec::new();
    let cfg = LabelConfig::default().scaled_to(trials.first().map_or(PAPER_RATE_HZ, |t| t.rate_hz));
    for &kind in kinds {
        let mut ev = Vec::new();
        for (ck, blob) in &g.members {
            let h = ck.heldout_trials();
            let test: Vec<&Trial> = trials
                .iter()
                .filter(|t| h.as_ref().is_none_or(|h| h.contains(&t.id)))
                .collect();
            let bytes = match blob {
                Some(b) => b.clone(),
                None => quantize_model(&ck.model, &[])?,
            };
            let aligned = slipguard_core::blob::AlignedBlob::new(&bytes);
            let m = slipguard_core::model::Model::from_bytes(aligned.as_bytes())
                .map_err(|e| anyhow::anyhow!("{}: the model blob does not parse: {e}", g.name))?;
            let q = (kind == Kind::Quantized).then_some(&m);
            ev.extend(slipguard_learn::hand::paper_sequences(
                &ck.model, q, &test, &cfg,
            ));
        }
        if ev.is_empty() {
            continue;
        }
        rows.push(Row {
            model: g.name.clone(),
            data: format!(
                "{} (hand level)",
                if cv { "real held-out" } else { "real (all)" }
            ),
            kind,
            metrics: slipguard_data::metrics::evaluate(
                &ev,
                slipguard_data::metrics::EventConfig::default(),
            ),
        });
    }
    Ok(rows)
}

/// Held-out description of a group: "fold k: ids" lines.
pub fn heldout_lines(g: &Group) -> Vec<String> {
    g.members
        .iter()
        .filter_map(|(ck, _)| {
            let h = ck.heldout_trials()?;
            Some(format!(
                "{} {}: {}",
                g.name,
                ck.extra.get("fold").map_or("", String::as_str),
                h.join(", ")
            ))
        })
        .collect()
}

/// `slipguard eval`: the decision overrides, the data sets, every model on them, then the
/// report (stdout and `--markdown`), the operating-curve plots and the JSON.
pub fn run(a: Args) -> anyhow::Result<()> {
    let mut groups = resolve(&a.models, a.allow_bad_model, &mut |w| eprintln!("{w}"))?;
    apply_overrides(&mut groups, &a);
    let data = DataSets::load(&a, &groups)?;
    for e in &data.skipped {
        eprintln!("eval: skipped {e}");
    }
    let (rows, notes, products) = evaluate(&groups, &data, &a)?;
    for p in products.iter().filter(|p| p.in_sample) {
        eprintln!(
            "note: {} is evaluated on real trials it was trained on (in-sample); its held-out figures come from `slipguard train --cv 5` or a folder of fold checkpoints",
            p.name
        );
    }
    let text = report_text(&products, &rows, &notes, &data.skipped);
    print!("{text}");
    if let Some(p) = &a.markdown {
        std::fs::write(p, &text).with_context(|| format!("writing {}", p.display()))?;
    }
    if let Some(d) = &a.plots {
        plot_curves(d, &products)?;
        eprintln!("plots in {}", d.display());
    }
    if let Some(path) = &a.json {
        write_json(path, &products, &rows, &data.skipped)?;
        eprintln!("figures in {}", path.display());
    }
    Ok(())
}

/// `--threshold`, `--raise-after`, `--clear-after` on every model; a member whose decision
/// changed loses its shipped blob (it carries the old decision) and is quantized afresh.
fn apply_overrides(groups: &mut [Group], a: &Args) {
    for g in groups {
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
                *blob = None;
            }
        }
    }
}

/// The data every model is evaluated on.
struct DataSets {
    /// The recordings' rate, unit and profile (one per data set; the loader checks), `None`
    /// without real trials.
    key: Option<(Millihertz, InputUnit, ProfileId)>,
    /// The real trials' labelled sequences from each channel's contact onset.
    real: Vec<Sequence>,
    /// Simulated force sequences (only when a force model is evaluated).
    sim_force: Vec<Sequence>,
    /// Simulated suction sequences (only when a suction model is evaluated).
    sim_suction: Vec<Sequence>,
    /// Suction calibration inputs for suction models without a blob.
    calib_suction: Vec<Sequence>,
    /// The real trials the armed window scores.
    scored: Vec<Trial>,
    /// The ones it cannot (a failure with no drop in its force; no lift mark while others
    /// have one): skipped and named, not refusing the data set.
    skipped: Vec<product::ArmedError>,
}

impl DataSets {
    /// Loads the real trials (unless `--no-real`), refuses a `--data` folder at another rate
    /// or unit than a model's, and draws the simulated sets the models' units need.
    fn load(a: &Args, groups: &[Group]) -> anyhow::Result<Self> {
        let real_trials: Vec<Trial> = if a.no_real {
            Vec::new()
        } else {
            load_real_trials(a.data.as_deref())?.1
        };
        let key = real_trials
            .first()
            .map(|t| {
                let profile = slipguard::replay::profile_for(t, &t.id)?;
                anyhow::Ok((t.rate_mhz(), profile.unit, profile.id))
            })
            .transpose()?;
        if let (Some(d), Some((r, u, _))) = (&a.data, key)
            && let Some(g) = groups.iter().find(|g| !fits(key, g))
        {
            let c = &g.members[0].0.model.config;
            anyhow::bail!(
                "{}: a {} Hz model in {}, but {} holds {} Hz recordings in {u}: evaluate it on recordings at its rate and unit",
                g.name,
                c.sample_rate_mhz.hz(),
                c.input_unit,
                d.display(),
                r.hz()
            );
        }
        let data_rate_mhz = key.map_or(PAPER_RATE_MHZ, |k| k.0);
        // The paper's metrics on the sequences the firmware's model state sees: from each
        // channel's contact onset (the data's sensor and rate).
        let suction_rule = OnsetRule::of(&slipguard_learn::evaluation::suction_config(
            slipguard_core::blob::Variant::Lstm,
            false,
            1,
            "",
        ));
        let force_rule = |rate| {
            OnsetRule::of(&slipguard_learn::evaluation::force_config(
                slipguard_core::blob::Variant::Lstm,
                false,
                1,
                "",
                rate,
            ))
        };
        let data_rule = match key.map(|k| k.2) {
            Some(ProfileId::Suction) => suction_rule,
            Some(ProfileId::Hand) | None => force_rule(data_rate_mhz),
        };
        let data_label = LabelConfig::default().scaled_to(data_rate_mhz.hz_f32());
        let real = product::cut_to_contact(sequences_of(&real_trials, &data_label), &data_rule);
        let needs = |u: InputUnit| {
            groups.iter().any(|g| {
                g.members
                    .iter()
                    .any(|(c, _)| c.model.config.input_unit == u)
            })
        };
        let sim_force = if needs(InputUnit::MilliNewton) {
            product::cut_to_contact(
                sim_force_sequences(a.sim_seed, a.sim_force, 0.3, PAPER_RATE_HZ),
                &force_rule(PAPER_RATE_MHZ),
            )
        } else {
            Vec::new()
        };
        let sim_suction = if needs(InputUnit::Counts) {
            product::cut_to_contact(
                sim_suction_sequences(a.sim_seed, a.sim_suction, 0.3),
                &suction_rule,
            )
        } else {
            Vec::new()
        };
        let refs: Vec<&Trial> = real_trials.iter().collect();
        let (keep, skipped) = product::scoreable(&refs, &LabelConfig::default())?;
        let scored: Vec<Trial> = keep.into_iter().cloned().collect();
        Ok(DataSets {
            key,
            real,
            sim_force,
            sim_suction,
            calib_suction: sim_suction_sequences(999, 16, 0.3),
            scored,
            skipped,
        })
    }

    /// Calibration inputs of a checkpoint without a blob: up to 64 real sequences outside its
    /// held-out trials.
    fn real_calib(&self, ck: &Checkpoint) -> Vec<Vec<f32>> {
        let h = ck.heldout_trials().unwrap_or_default();
        self.real
            .iter()
            .filter(|s| !h.contains(&s.cs.trial_id))
            .take(64)
            .map(|s| s.cs.samples.clone())
            .collect()
    }
}

/// Whether every member of `g` is at the real data's rate and unit (`key`).
fn fits(key: Option<(Millihertz, InputUnit, ProfileId)>, g: &Group) -> bool {
    key.is_some_and(|(r, u, _)| {
        g.members
            .iter()
            .all(|(c, _)| c.model.config.sample_rate_mhz == r && c.model.config.input_unit == u)
    })
}

/// Every model on the data sets it fits: the paper's rows (float and quantized), the held-out
/// lines of CV groups, and the armed-window products on the real trials.
fn evaluate(
    groups: &[Group],
    data: &DataSets,
    a: &Args,
) -> anyhow::Result<(Vec<Row>, Vec<String>, Vec<Product>)> {
    let plots = a.plots.as_deref().map(|d| (d, a.plot_count));
    let kinds = [Kind::Float, Kind::Quantized];
    let mut rows = Vec::new();
    let mut notes = Vec::new();
    let mut products: Vec<Product> = Vec::new();
    let real_calib = |ck: &Checkpoint| data.real_calib(ck);
    for g in groups {
        let unit = g.members[0].0.model.config.input_unit;
        if g.members[0].0.model.config.variant.is_hand() {
            // One network per grasp: the paper's metrics over hand sequences, no per-channel
            // rows; simulated sets are per channel.
            if !data.scored.is_empty() && fits(data.key, g) {
                let cv = g.members.iter().all(|(c, _)| c.heldout_trials().is_some());
                rows.extend(hand_paper_rows(g, &data.scored, cv, &kinds)?);
                notes.extend(heldout_lines(g));
                products.push(product_eval(g, &data.scored, &data.real, &real_calib, cv)?);
            }
            continue;
        }
        if !data.real.is_empty() && fits(data.key, g) {
            let cv = g.members.iter().all(|(c, _)| c.heldout_trials().is_some());
            let name = if cv { "real held-out" } else { "real (all)" };
            rows.extend(eval_group(
                g,
                name,
                &data.real,
                |ck, s| {
                    ck.heldout_trials()
                        .is_none_or(|h| h.contains(&s.cs.trial_id))
                },
                real_calib,
                plots,
                &kinds,
            )?);
            notes.extend(heldout_lines(g));
            products.push(product_eval(g, &data.scored, &data.real, &real_calib, cv)?);
        }
        if unit == InputUnit::MilliNewton {
            if !data.sim_force.is_empty() {
                // CV groups: fold 0 stands for the recipe on simulated data.
                let g0 = Group {
                    name: g.name.clone(),
                    members: vec![g.members[0].clone()],
                };
                rows.extend(eval_group(
                    &g0,
                    &format!("sim force seed {}", a.sim_seed),
                    &data.sim_force,
                    |_, _| true,
                    real_calib,
                    plots,
                    &kinds,
                )?);
            }
        } else if !data.sim_suction.is_empty() {
            let calib = |_: &Checkpoint| -> Vec<Vec<f32>> {
                data.calib_suction
                    .iter()
                    .map(|s| s.cs.samples.clone())
                    .collect()
            };
            rows.extend(eval_group(
                g,
                &format!("sim suction 71 Hz seed {}", a.sim_seed),
                &data.sim_suction,
                |_, _| true,
                calib,
                plots,
                &kinds,
            )?);
        }
    }
    Ok((rows, notes, products))
}

/// The report: the armed-window table with its notes (the rule, the fused decisions, the
/// skipped trials), then the paper's table and the held-out trials per fold.
fn report_text(
    products: &[Product],
    rows: &[Row],
    notes: &[String],
    skipped: &[product::ArmedError],
) -> String {
    let mut text = String::new();
    if !products.is_empty() {
        text.push_str(ARMED_HEADER);
        text.push('\n');
        for p in products {
            text.push_str(&armed_row(p));
            text.push('\n');
        }
        text.push_str(ARMED_NOTE);
        text.push_str(RULE_NOTE);
        for p in products {
            if let Some(f) = &p.hand_rule {
                text.push_str(&format!("\n\n{}", fused_note(&p.name, f)));
            }
        }
        for p in products {
            if let Some(r) = &p.rule {
                text.push_str(&format!(
                    "\n\n{}: load rule picked {}: {}.",
                    p.name, r.how, r.picks
                ));
            }
        }
        for p in products {
            if let Some((hand, rule)) = &p.label_txt {
                text.push_str(&format!(
                    "\n\n{}: {} of the scored trials have marks estimated from the force \
                     (docs/labels.md); on the {} with recorded marks (label.txt) only: {} {}{}.",
                    p.name,
                    p.estimated,
                    hand.metrics.grasps,
                    hand_level(p),
                    hand.summary(),
                    rule.as_ref()
                        .map_or(String::new(), |r| format!("; load rule {}", r.summary()))
                ));
            }
        }
        if !skipped.is_empty() {
            text.push_str("\n\nSkipped (not scored in the armed window):\n");
            for e in skipped {
                text.push_str(&format!("\n- {e}"));
            }
        }
        text.push_str("\n\nThe paper's metrics (per channel, from each channel's contact onset to the end of the 160-step window):\n\n");
    }
    text.push_str(TABLE_HEADER);
    text.push('\n');
    for r in rows {
        text.push_str(&row_markdown(r));
        text.push('\n');
    }
    if !notes.is_empty() {
        text.push_str("\nHeld-out trials per fold:\n\n");
        for n in notes {
            text.push_str(&format!("- {n}\n"));
        }
    }
    text
}

/// `--plots`: each product's operating curve with the rule beside it.
fn plot_curves(d: &Path, products: &[Product]) -> anyhow::Result<()> {
    for p in products {
        let slug: String = p
            .name
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        let path = d.join(format!("operating-curve-{slug}.png"));
        slipguard::plot::plot_operating_curve_with_rule(
            &p.curve,
            p.shipped.as_ref(),
            p.rule.as_ref().map(|r| (r.curve.as_slice(), &r.point)),
            &format!(
                "{}: hand level, armed window, {} grasps",
                p.name, p.hand.metrics.grasps
            ),
            &path,
        )?;
    }
    Ok(())
}

/// `--json`: one object per product (an array for several) with the skipped trials.
fn write_json(
    path: &Path,
    products: &[Product],
    rows: &[Row],
    skipped: &[product::ArmedError],
) -> anyhow::Result<()> {
    let objs: Vec<serde_json::Value> = products
        .iter()
        .map(|p| {
            let q = rows.iter().find(|r| {
                r.model == p.name && r.kind == Kind::Quantized && r.data.starts_with("real")
            });
            let mut v = product_json(p, q);
            if let Some(o) = v.as_object_mut() {
                o.insert(
                    "skipped".into(),
                    serde_json::json!(
                        skipped
                            .iter()
                            .map(|e| serde_json::json!({
                                "trial": skipped_trial(e),
                                "reason": e.to_string(),
                            }))
                            .collect::<Vec<_>>()
                    ),
                );
            }
            v
        })
        .collect();
    let v = if objs.len() == 1 {
        objs.into_iter().next().unwrap_or_default()
    } else {
        serde_json::Value::Array(objs)
    };
    let text = serde_json::to_string_pretty(&v).context("encoding the figures as JSON")?;
    std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))
}

/// The trial an armed-window error names.
fn skipped_trial(e: &product::ArmedError) -> String {
    e.trial().to_string()
}

fn product_eval(
    g: &Group,
    trials: &[Trial],
    real: &[Sequence],
    calib: &impl Fn(&Checkpoint) -> Vec<Vec<f32>>,
    cv: bool,
) -> anyhow::Result<Product> {
    // The paper's label durations at the recordings' rate.
    let cfg = LabelConfig::default().scaled_to(trials.first().map_or(PAPER_RATE_HZ, |t| t.rate_hz));
    let mut hand: Vec<ArmedGrasp> = Vec::new();
    let mut channel: Vec<ArmedGrasp> = Vec::new();
    let mut curve_runs: Vec<(product::WindowedRun, slipguard_core::decision::HandConfig)> =
        Vec::new();
    let (mut seqs, mut preds) = (Vec::new(), Vec::new());
    for (ck, blob) in &g.members {
        let h = ck.heldout_trials();
        let test: Vec<&Trial> = trials
            .iter()
            .filter(|t| h.as_ref().is_none_or(|h| h.contains(&t.id)))
            .collect();
        let bytes = match blob {
            Some(b) => b.clone(),
            None => {
                let c = calib(ck);
                let c: Vec<&[f32]> = c.iter().map(Vec::as_slice).collect();
                quantize_model(&ck.model, &c)?
            }
        };
        let aligned = slipguard_core::blob::AlignedBlob::new(&bytes);
        let m = slipguard_core::model::Model::from_bytes(aligned.as_bytes())
            .map_err(|e| anyhow::anyhow!("{}: the model blob does not parse: {e}", g.name))?;
        let hc = slipguard_core::decision::HandConfig::of(m.config());
        for w in product::windowed_runs(&m, &test, &cfg)? {
            let t = test.iter().find(|t| t.id == w.trial).copied();
            if let Some(t) = t
                && let Some(sc) = product::score(t, &w.run, &cfg)?
            {
                hand.push(sc.hand);
                channel.extend(sc.channels);
            }
            curve_runs.push((w, hc));
        }
        let ts: Vec<&Sequence> = real
            .iter()
            .filter(|s| h.as_ref().is_none_or(|h| h.contains(&s.cs.trial_id)))
            .collect();
        let p = probabilities(&ck.model, &bytes, Kind::Quantized, &ts)?;
        let d = DecisionConfig::of(&ck.model.config);
        preds.extend(p.iter().map(|q| decide(d, q)));
        seqs.extend(ts);
    }
    // The curve: every member's runs, the threshold and hysteresis swept together.
    let mut curve = Vec::new();
    for &r in &product::CURVE_RAISE_AFTER {
        for &th in &product::CURVE_THRESHOLDS {
            let grasps: Vec<ArmedGrasp> = curve_runs
                .iter()
                .map(|(w, hc)| {
                    let mut h = *hc;
                    h.decision.threshold_q15 = Q15::from_f64(th).header_threshold() as i16;
                    h.decision.raise_after = r;
                    w.grasp_with(&h)
                })
                .collect();
            curve.push(CurvePoint::of(th, r, &grasps));
        }
    }
    let rule = match g.members.first() {
        Some((ck, _)) => {
            let folds: Vec<Vec<String>> = g
                .members
                .iter()
                .filter_map(|(ck, _)| ck.heldout_trials())
                .collect();
            Some(slipguard_learn::load_rule::beside_model(
                trials,
                &ck.model.config,
                cv.then_some(folds.as_slice()),
            )?)
        }
        None => None,
    };
    let shipped = g.members.first().map(|(ck, _)| {
        let c = &ck.model.config;
        CurvePoint::of(Q15(c.threshold_q15 as i16).to_f64(), c.raise_after, &hand)
    });
    // The blob's rule (format v2) is in every run of its members (`HandRun::rule`).
    let hand_rule = curve_runs.iter().find_map(|(w, _)| w.run.rule);
    let estimated: Vec<String> = trials
        .iter()
        .filter(|t| t.label_estimated() && hand.iter().any(|g| g.trial == t.id))
        .map(|t| t.id.clone())
        .collect();
    let label_txt = slipguard::armed_table::label_txt_only(&hand, rule.as_ref(), &estimated);
    Ok(Product {
        estimated: estimated.len(),
        label_txt,
        name: g.name.clone(),
        in_sample: !cv,
        hand: ArmedReport::of(&hand),
        channel: ArmedReport::of(&channel),
        curve,
        shipped,
        paper_success_ci: product::bootstrap_paper(&seqs, &preds, 5, |m| m.success_rate),
        paper_ahead_ci: product::bootstrap_paper(&seqs, &preds, 6, |m| m.ahead_drop_rate),
        rule,
        hand_rule,
    })
}

fn product_json(p: &Product, paper: Option<&Row>) -> serde_json::Value {
    use serde_json::json;
    let mut o = serde_json::Map::new();
    o.insert("model".into(), json!(p.name));
    o.insert(
        "data".into(),
        json!(if p.in_sample {
            "real (all, in-sample)"
        } else {
            "real held-out"
        }),
    );
    let ci = |i: Option<slipguard_data::armed::Interval>| {
        i.map_or(serde_json::Value::Null, |i| json!([i.lo, i.hi]))
    };
    if let Some(r) = paper {
        o.insert("paper.success_rate".into(), json!(r.metrics.success_rate));
        o.insert("paper.success_rate_ci".into(), ci(p.paper_success_ci));
        o.insert("paper.ahead_drop".into(), json!(r.metrics.ahead_drop_rate));
        o.insert("paper.ahead_drop_ci".into(), ci(p.paper_ahead_ci));
        o.insert(
            "paper.false_alarm_rate".into(),
            json!(r.metrics.false_alarm_rate),
        );
    }
    o.extend(p.hand.to_json("armed"));
    o.insert("data.estimated_marks_trials".into(), json!(p.estimated));
    if let Some((hand, rule)) = &p.label_txt {
        o.extend(hand.to_json("armed_label_txt"));
        if let Some(r) = rule {
            o.extend(r.to_json("baseline.load_rule.armed_label_txt"));
        }
    }
    // "hand" or "hand (fused)": what the armed.* figures score (outside armed.*, whose keys
    // the baseline repeats).
    o.insert("hand_level".into(), json!(hand_level(p)));
    if let Some(f) = &p.hand_rule {
        o.insert(
            "hand_rule".into(),
            json!({
                "description": f.to_string(),
                "strict_q15": f.strict.fraction_q15,
                "guard_q15": f.guard_q15,
                "window_frames": f.strict.window,
            }),
        );
    }
    o.extend(p.channel.to_json("armed_channel"));
    if let Some(r) = &p.rule {
        o.extend(r.report.to_json("baseline.load_rule.armed"));
        o.insert("baseline.load_rule.picked".into(), json!(r.how));
        o.insert(
            "baseline.load_rule.operating_curve".into(),
            json!(
                r.curve
                    .iter()
                    .map(|c| json!({
                        "fraction": c.threshold,
                        "window_frames": c.raise_after,
                        "detected": c.detected_rate * c.failures as f64,
                        "detected_300ms": c.detected_300ms,
                        "false_alarm_grasps": c.false_alarm_grasps,
                        "lead_median_ms": c.lead_median_ms,
                    }))
                    .collect::<Vec<_>>()
            ),
        );
        o.insert(
            "baseline.load_rule.folds".into(),
            json!(
                r.per_fold
                    .iter()
                    .map(|(t, rule)| json!({
                        "heldout_trials": t,
                        "fraction": slipguard_learn::load_rule::fraction(rule),
                        "window_frames": rule.window,
                    }))
                    .collect::<Vec<_>>()
            ),
        );
    }
    if let Some(s) = &p.shipped {
        o.insert("armed.threshold".into(), json!(s.threshold));
        o.insert("armed.raise_after".into(), json!(s.raise_after));
    }
    o.insert(
        "armed.operating_curve".into(),
        json!(
            p.curve
                .iter()
                .map(|c| json!({
                    "threshold": c.threshold,
                    "raise_after": c.raise_after,
                    "detected_rate": c.detected_rate,
                    "false_alarm_grasp_rate": c.false_alarm_grasp_rate,
                    "lead_median_ms": c.lead_median_ms,
                }))
                .collect::<Vec<_>>()
        ),
    );
    serde_json::Value::Object(o)
}

#[cfg(test)]
mod tests {
    use super::*;
    use slipguard_learn::load_rule::RuleEval;

    fn grasp(trial: &str, failure: bool, up: &[usize]) -> ArmedGrasp {
        let mut flags = vec![false; 30];
        for &i in up {
            flags[i] = true;
        }
        ArmedGrasp {
            trial: trial.into(),
            failure,
            start: 5,
            end: 25,
            flags,
            step_ms: 60.0,
        }
    }

    #[test]
    fn the_rule_is_written_under_baseline_with_the_models_keys() {
        let model = vec![grasp("f", true, &[10]), grasp("s", false, &[])];
        let rule = vec![grasp("f", true, &[20]), grasp("s", false, &[12])];
        let point = CurvePoint::of(0.4, 10, &rule);
        let p = Product {
            name: "m".into(),
            in_sample: false,
            hand: ArmedReport::of(&model),
            channel: ArmedReport::of(&model),
            curve: Vec::new(),
            shipped: None,
            paper_success_ci: None,
            paper_ahead_ci: None,
            hand_rule: None,
            estimated: 0,
            label_txt: None,
            rule: Some(RuleEval {
                how: "leave one trial out".into(),
                picks: String::new(),
                per_fold: vec![(
                    vec!["f".into()],
                    slipguard_core::decision::LoadRule {
                        fraction_q15: 13_107,
                        window: 10,
                    },
                )],
                grasps: rule.clone(),
                report: ArmedReport::of(&rule),
                point,
                curve: vec![point],
            }),
        };
        let v = product_json(&p, None);
        let o = v.as_object().unwrap();
        let armed: Vec<&str> = o
            .keys()
            .filter_map(|k| k.strip_prefix("armed."))
            .filter(|k| !matches!(*k, "operating_curve" | "threshold" | "raise_after"))
            .collect();
        assert!(armed.contains(&"detected") && armed.contains(&"false_alarm_grasp_rate_ci"));
        for k in &armed {
            assert!(
                o.contains_key(&format!("baseline.load_rule.armed.{k}")),
                "baseline.load_rule.armed.{k} missing"
            );
        }
        // The rule's own figures, not the model's: lead 5 steps · 60 ms, one false-alarm grasp.
        assert_eq!(o["armed.leads_ms"], serde_json::json!([900.0]));
        assert_eq!(
            o["baseline.load_rule.armed.leads_ms"],
            serde_json::json!([300.0])
        );
        assert_eq!(o["baseline.load_rule.armed.false_alarm_grasps"], 1);
        assert_eq!(o["armed.false_alarm_grasps"], 0);
        assert_eq!(o["baseline.load_rule.folds"][0]["window_frames"], 10);
        // The table has the rule's row under the model's.
        let rows = armed_row(&p);
        assert!(
            rows.lines()
                .nth(2)
                .unwrap()
                .starts_with("| load rule beside m |")
        );
        assert!(rows.starts_with("| m | real held-out | hand |"), "{rows}");
        assert_eq!(o["hand_level"], "hand");
        assert!(!o.contains_key("hand_rule"));

        // A blob with a hand rule: the hand row says it is the fused flag, the JSON carries the
        // rule, and the baseline row stays.
        let f = slipguard_core::decision::FusedHand {
            strict: slipguard_core::decision::LoadRule {
                fraction_q15: 13_107,
                window: 10,
            },
            guard_q15: 26_214,
        };
        let fused = Product {
            hand_rule: Some(f),
            ..p
        };
        let rows = armed_row(&fused);
        assert!(
            rows.starts_with("| m | real held-out | hand (fused) |"),
            "{rows}"
        );
        assert!(rows.contains("| load rule beside m |"));
        let v = product_json(&fused, None);
        assert_eq!(v["hand_level"], "hand (fused)");
        assert_eq!(v["hand_rule"]["window_frames"], 10);
        assert_eq!(v["hand_rule"]["guard_q15"], 26_214);
        assert!(v.get("baseline.load_rule.armed.detected").is_some());
        assert!(fused_note("m", &f).contains("rule < 0.40·peak"));
    }
}
