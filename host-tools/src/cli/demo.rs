//! `slipguard demo`: the README's main command. Runs the shipped quantized blobs through the
//! bit-exact core (`slipguard_core::model::Model`): the hand-force model on the shared real
//! trials and on a seeded simulated force set, the suction model on simulated suction data;
//! prints one table and writes Fig. 8-style plots.
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use slipguard::plot::plot_prediction;
use slipguard_core::blob::AlignedBlob;
use slipguard_core::model::Model;
use slipguard_core::sample::{PAPER_RATE_HZ, PAPER_RATE_MHZ};
use slipguard_learn::evaluation::{
    Kind, Row, Sequence, TABLE_HEADER, decide, metrics_of, quant_p_q15_many, row_markdown,
    sim_force_sequences, sim_suction_sequences,
};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Real data (default: $SLIPGUARD_DATA or <repo>/data/eagle-shoal).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Folder with `hand-force/` and `suction/` (default: <repo>/models).
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Folder for the plots.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Simulated trials per sensor.
    #[arg(long, default_value_t = 60)]
    pub sim_count: usize,
    /// Seed of the simulated sets (the shipped models trained on seeds 11 and 12).
    #[arg(long, default_value_t = 2024)]
    pub sim_seed: u64,
    /// Plots per data set.
    #[arg(long, default_value_t = 4)]
    pub plot_count: usize,
}

/// Default models folder: `<repo>/models`.
pub fn default_models_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models")
}

fn run_blob(
    name: &str,
    blob: &[u8],
    data_name: &str,
    seqs: &[Sequence],
    plots: (&Path, usize),
) -> anyhow::Result<Row> {
    let aligned = AlignedBlob::new(blob);
    let model = Model::from_bytes(aligned.as_bytes())
        .map_err(|e| anyhow::anyhow!("{name}: blob does not parse: {e:?}"))?;
    let d = model.decision();
    let refs: Vec<&Sequence> = seqs.iter().collect();
    let samples: Vec<&[f32]> = refs.iter().map(|s| s.cs.samples.as_slice()).collect();
    let preds: Vec<_> = quant_p_q15_many(&model, &samples)
        .iter()
        .map(|p| decide(d, p))
        .collect();
    let (dir, n) = plots;
    let mut idx: Vec<usize> = (0..refs.len()).collect();
    idx.sort_by_key(|&i| !refs[i].failure());
    let mut picked: Vec<usize> = idx.iter().copied().take(n.saturating_sub(1)).collect();
    if let Some(&s) = idx.iter().find(|&&i| !refs[i].failure()) {
        picked.push(s);
    }
    for i in picked {
        let s = refs[i];
        let file = format!(
            "{name}-{}-{}-c{}.png",
            data_name.split_whitespace().next().unwrap_or("data"),
            s.cs.trial_id,
            s.cs.channel
        );
        let title = format!(
            "{name} (quantized core) on {} c{}",
            s.cs.trial_id, s.cs.channel
        );
        plot_prediction(s, &preds[i], &title, &dir.join(file))?;
    }
    Ok(Row {
        model: name.to_string(),
        data: data_name.to_string(),
        kind: Kind::Quantized,
        metrics: metrics_of(&refs, &preds),
    })
}

fn read_blob(dir: &Path, name: &str) -> anyhow::Result<Vec<u8>> {
    let p = dir.join(name).join(format!("{name}.bin"));
    std::fs::read(&p).with_context(|| {
        format!(
            "reading the shipped model {} (run from the repository, or pass --models)",
            p.display()
        )
    })
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let models = a.models.clone().unwrap_or_else(default_models_dir);
    let hand = read_blob(&models, "hand-force")?;
    let suction = read_blob(&models, "suction")?;
    let (path, trials) = super::train::load_real_trials(a.data.as_deref())?;
    let rule = slipguard_learn::product::OnsetRule::of(&slipguard_learn::evaluation::force_config(
        slipguard_core::blob::Variant::Force,
        false,
        1,
        "",
        PAPER_RATE_MHZ,
    ));
    let real = slipguard_learn::product::cut_to_contact(
        slipguard_learn::evaluation::sequences_of(
            &trials,
            &slipguard_data::labels::LabelConfig::default(),
        ),
        &rule,
    );
    let armed = super::eval::armed_rows_for_blob("hand-force", &hand, &trials, true)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let plots = (a.out.as_path(), a.plot_count);
    let mut rows = Vec::new();
    let n_trials = {
        let mut ids: Vec<&str> = real.iter().map(|s| s.cs.trial_id.as_str()).collect();
        ids.sort();
        ids.dedup();
        ids.len()
    };
    rows.push(run_blob(
        "hand-force",
        &hand,
        &format!("real, {n_trials} trials with contact"),
        &real,
        plots,
    )?);
    let sf = slipguard_learn::product::cut_to_contact(
        sim_force_sequences(a.sim_seed, a.sim_count, 0.3, PAPER_RATE_HZ),
        &rule,
    );
    rows.push(run_blob(
        "hand-force",
        &hand,
        &format!(
            "simulated force, {} trials, seed {}",
            a.sim_count, a.sim_seed
        ),
        &sf,
        plots,
    )?);
    let ss = sim_suction_sequences(a.sim_seed, a.sim_count, 0.3);
    rows.push(run_blob(
        "suction",
        &suction,
        &format!(
            "simulated suction 71 Hz, {} trials, seed {}",
            a.sim_count, a.sim_seed
        ),
        &ss,
        plots,
    )?);
    println!(
        "slipguard demo: shipped blobs from {} through the bit-exact core; real data {}",
        models.display(),
        path.display()
    );
    println!(
        "\nAs a grip controller uses the flags (real trials, quantized model, the firmware's decision stage):\n"
    );
    println!("{}", super::eval::ARMED_HEADER);
    println!("{armed}");
    println!("{}", super::eval::ARMED_NOTE);
    println!(
        "\nThe paper's metrics (per channel sequence; success rate = correct steps, ahead-drop = a flag before the drop; false alarms = successes with any flag; lead; event precision / recall):\n"
    );
    println!("{TABLE_HEADER}");
    for r in &rows {
        println!("{}", row_markdown(r));
    }
    println!(
        "\nNote: the hand-force model was trained on these real trials (in-sample); its held-out \
         figures are in models/hand-force/README.md and docs/results.md."
    );
    println!(
        "plots: {} ({:.1} s)",
        a.out.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
