//! `slipguard simulate`: generate force or suction trials, or `--validate`
//! the force simulator against the real trials and write the report.
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use plotters::style::RGBColor;
use slipguard::plot;
use slipguard_app::profile::ProfileId;
use slipguard_data::labels::LabelConfig;
use slipguard_data::{Outcome, Trial, eagle, load_path, recording};
use slipguard_sim::dsp;
use slipguard_sim::force::PAPER_RATE_HZ;
use slipguard_sim::force::{self, ForceSimConfig, Intent};
use slipguard_sim::suction::{self, SuctionSimConfig};
use slipguard_sim::validate::{self, TrialStats};

use super::progress::bar;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Sensor set-up to simulate: force (the hand profile's 16 fingertip pads, mN) or suction
    /// (the suction profile's 4 cups, 16-bit counts, written at 71 Hz and 17.75 Hz).
    #[arg(long, value_parser = super::check::sensor(), default_value = "force")]
    pub sensor: ProfileId,
    /// Sample rate of force trials, Hz (1 to 500: the physics runs at 1 kHz; default 16.7, the
    /// dataset's; 40 = the DoraHand). Suction trials are always written at 71 Hz and 17.75 Hz.
    #[arg(long, value_parser = rate_hz, allow_negative_numbers = true)]
    pub rate: Option<f64>,
    /// Number of trials (count, 1 to 1 000 000; default 10, 100 with --validate). Refused before
    /// simulating when the samples would not fit in memory (2 GB).
    #[arg(long, value_parser = super::check::usize_in!(1..=1_000_000), allow_negative_numbers = true)]
    pub count: Option<usize>,
    /// Seed (integer ≥ 0); the same seed gives byte-identical trials.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    pub seed: u64,
    /// Share of trials drawn with marginal (dropping) parameters (0 to 1).
    #[arg(long, default_value_t = 0.3, value_parser = super::check::unit, allow_negative_numbers = true)]
    pub failure_share: f64,
    /// Write the trials as slipguard recordings into this folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Draw PNGs of the first 4 trials into this folder.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Compare the force simulator with the real trials and write the report.
    #[arg(long)]
    pub validate: bool,
    /// Real data for --validate (default: $SLIPGUARD_DATA or <repo>/data/eagle-shoal).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Folder for the report (`simulator-validation.md`) and its `img/` (default: `docs` in the
    /// current folder, the repository's when run from its root).
    #[arg(long)]
    pub report_dir: Option<PathBuf>,
}

/// Lowest and highest `--rate`, Hz: below 1 Hz a trial has a few samples; the physics is
/// integrated at [`force::INTERNAL_HZ`] (1 kHz), so above its Nyquist rate the output would be
/// interpolation.
pub const RATE_RANGE_HZ: (f64, f64) = (1.0, force::INTERNAL_HZ / 2.0);

/// Samples the simulated trials may hold in memory, bytes (they are all kept before writing).
pub const MAX_SAMPLE_BYTES: f64 = 2e9;

/// clap parser of `--rate`: a number of Hz in [`RATE_RANGE_HZ`].
fn rate_hz(s: &str) -> Result<f64, String> {
    let (lo, hi) = RATE_RANGE_HZ;
    match s.trim().parse::<f64>() {
        Ok(v) if (lo..=hi).contains(&v) => Ok(v),
        _ => Err(format!(
            "`{s}` is not a rate in the allowed range {lo}..={hi} Hz (the simulator's physics \
             runs at {} Hz)",
            force::INTERNAL_HZ
        )),
    }
}

/// The bytes of samples `count` trials hold (f32 per channel and step), checked against
/// [`MAX_SAMPLE_BYTES`] before any trial is simulated.
fn check_memory(sensor: ProfileId, rate: f64, count: usize) -> anyhow::Result<()> {
    let per_trial = match sensor {
        ProfileId::Hand => {
            let cfg = ForceSimConfig::at_rate(rate);
            cfg.n_steps() as f64 * cfg.n_channels as f64 * 4.0
        }
        ProfileId::Suction => {
            let cfg = SuctionSimConfig::default();
            // The 71 Hz trial and its 17.75 Hz copy, 4 cups.
            cfg.duration_s * cfg.rate_hz * (1.0 + 1.0 / cfg.decimate as f64) * 4.0 * 4.0
        }
    };
    let total = per_trial * count as f64;
    if total > MAX_SAMPLE_BYTES {
        bail!(
            "{count} trials at {rate} Hz would hold {:.1} GB of samples in memory (limit {:.0} GB): \
             lower --count or --rate, or simulate in several runs with different --seed",
            total / 1e9,
            MAX_SAMPLE_BYTES / 1e9
        );
    }
    Ok(())
}

/// `slipguard simulate`, step by step: check the options, then either `--validate`
/// ([`validate_cmd`]) or simulate the trials, print their table, write them as recordings
/// and plot the first ones.
pub fn run(a: Args) -> anyhow::Result<()> {
    let (rate, count) = checked_rate_and_count(&a)?;
    if a.validate {
        return validate_cmd(&a);
    }
    let trials = simulate(&a, rate, count);
    print_table(&trials);
    if let Some(dir) = &a.out {
        write_recordings(dir, &trials)?;
    }
    if let Some(dir) = &a.plot {
        write_plots(dir, a.sensor, &trials)?;
    }
    Ok(())
}

/// The force rate (--rate, else the dataset's) and the trial count (--count, else 10, or
/// 100 with --validate), after the options that do not go together and the memory bound.
fn checked_rate_and_count(a: &Args) -> anyhow::Result<(f64, usize)> {
    if a.sensor == ProfileId::Suction && a.rate.is_some() {
        bail!("--rate applies to force trials; suction trials are written at 71 Hz and 17.75 Hz");
    }
    if a.validate && a.rate.is_some() {
        bail!(
            "--validate compares with the real trials at their {PAPER_RATE_HZ} Hz: leave out --rate"
        );
    }
    let rate = a.rate.unwrap_or(PAPER_RATE_HZ);
    let count = a.count.unwrap_or(if a.validate { 100 } else { 10 });
    check_memory(a.sensor, rate, count)?;
    Ok((rate, count))
}

/// `count` force trials at `cfg`'s rate from `seed`, with a progress bar.
fn simulate_force(seed: u64, count: usize, failure_share: f64, cfg: &ForceSimConfig) -> Vec<Trial> {
    let pb = bar(count as u64, "simulating");
    let t = force::simulate_batch(seed, count, failure_share, cfg, |i| {
        pb.set_position(i as u64)
    });
    pb.finish_and_clear();
    t
}

/// The trials of --sensor: force at `rate`, or suction (each trial at 71 Hz followed by its
/// 17.75 Hz copy).
fn simulate(a: &Args, rate: f64, count: usize) -> Vec<Trial> {
    match a.sensor {
        ProfileId::Hand => simulate_force(
            a.seed,
            count,
            a.failure_share,
            &ForceSimConfig::at_rate(rate),
        ),
        ProfileId::Suction => {
            let cfg = SuctionSimConfig::default();
            let pb = bar(count as u64, "simulating");
            let mut v = Vec::new();
            for i in 0..count {
                let (hi, lo) =
                    suction::simulate_trial(a.seed, i as u64, None, a.failure_share, &cfg);
                v.push(hi);
                v.push(lo);
                pb.inc(1);
            }
            pb.finish_and_clear();
            v
        }
    }
}

/// One line per trial on stdout: steps, rate, outcome, marks, slip and drop steps, contact
/// channels.
fn print_table(trials: &[Trial]) {
    println!(
        "{:<30} {:>6} {:>6} {:>8} {:>12} {:>5} {:>6}  contact",
        "trial", "steps", "Hz", "outcome", "l0/l1/l2", "slip", "drop"
    );
    for t in trials {
        let m = |x: Option<usize>| x.map_or("-".to_string(), |v| v.to_string());
        println!(
            "{:<30} {:>6} {:>6} {:>8} {:>12} {:>5} {:>6}  {:?}",
            t.id,
            t.n_steps(),
            t.rate_hz,
            t.outcome.to_string(),
            t.marks.to_string(),
            m(t.slip_onset_step),
            m(t.drop_step),
            t.contact_channels()
        );
    }
}

/// The trials as recordings in `dir`. One folder is one data set at one rate (`label` and
/// `train` refuse a mix): recordings at another rate than the first (suction's 17.75 Hz
/// copies) go into a subfolder.
fn write_recordings(dir: &Path, trials: &[Trial]) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let main_rate = trials.first().map_or(0.0, |t| t.rate_hz);
    for t in trials {
        let d = if t.rate_hz == main_rate {
            dir.to_path_buf()
        } else {
            dir.join(format!("{}hz", t.rate_hz))
        };
        std::fs::create_dir_all(&d).with_context(|| format!("creating {}", d.display()))?;
        recording::write_recording(t, &d.join(format!("{}.csv", t.id)))?;
    }
    println!(
        "wrote {} recordings to {} ({} Hz; other rates in subfolders)",
        trials.len(),
        dir.display(),
        main_rate
    );
    Ok(())
}

/// PNGs of the first 4 trials in `dir`.
fn write_plots(dir: &Path, sensor: ProfileId, trials: &[Trial]) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for t in trials.iter().take(4) {
        let p = dir.join(format!("{}.png", t.id));
        match sensor {
            ProfileId::Hand => plot::plot_trial(t, None, &p)?,
            ProfileId::Suction => plot::plot_stack(&[t], &p)?,
        }
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn repo_docs() -> PathBuf {
    PathBuf::from("docs")
}

/// Real trials shown side by side with simulated ones.
const PAIR_REAL: [&str; 3] = [
    "Cheez_100_814_top_3",
    "Water_100_1045_back_8",
    "Cola_100_26_top_3",
];

/// `--validate`, step by step: load the real trials, simulate as many force trials, measure
/// both with the same code, then the spectra, the side-by-side plot and the other set-ups'
/// examples; write the report and print its table.
fn validate_cmd(a: &Args) -> anyhow::Result<()> {
    let data = a.data.clone().unwrap_or_else(eagle::default_data_dir);
    let out = a.report_dir.clone().unwrap_or_else(repo_docs);
    let img = out.join("img");
    std::fs::create_dir_all(&img).with_context(|| format!("creating {}", img.display()))?;
    let lcfg = LabelConfig::default();
    let real = real_with_contact(&data, &lcfg)?;
    let count = a.count.unwrap_or(100);
    let sim = simulate_force(a.seed, count, a.failure_share, &ForceSimConfig::default());
    let (rs, ss) = measure(&real, &sim, &lcfg);
    let table = validate::comparison_table(&validate::compare(&rs, &ss));
    let spectra = Spectra::of(&rs, &ss);
    spectra.plot(&img)?;
    let used = side_by_side(&real, &sim, &img)?;
    let others = OtherSetups::simulate(a, &img)?;
    let v = Validation {
        a,
        count,
        data: &data,
        real: &real,
        sim: &sim,
        table: &table,
        spectra: &spectra,
        used: &used,
        others: &others,
    };
    let report = out.join("simulator-validation.md");
    std::fs::write(&report, v.report()).with_context(|| format!("writing {}", report.display()))?;
    println!("{}", table);
    println!(
        "spectra share 3-5 Hz: pre-drop real {} sim {}; hold real {} sim {}",
        band(&spectra.real_pre),
        band(&spectra.sim_pre),
        band(&spectra.real_hold),
        band(&spectra.sim_hold)
    );
    println!("wrote {} and images in {}", report.display(), img.display());
    Ok(())
}

/// The real trials under `data` at the dataset's rate with real contact (a success without
/// contact tells nothing about force levels).
fn real_with_contact(data: &Path, lcfg: &LabelConfig) -> anyhow::Result<Vec<Trial>> {
    let pb = bar(0, "loading");
    let real = load_path(data, lcfg, |i, n| {
        pb.set_length(n as u64);
        pb.set_position(i as u64);
    })
    .with_context(|| format!("loading {}", data.display()))?;
    pb.finish_and_clear();
    let real: Vec<Trial> = real
        .into_iter()
        .filter(|t| !t.contact_channels().is_empty() && t.rate_hz > 16.0 && t.rate_hz < 17.0)
        .collect();
    if real.is_empty() {
        bail!(
            "no real {PAPER_RATE_HZ} Hz trials with contact under {}",
            data.display()
        );
    }
    Ok(real)
}

/// Every trial's statistics (`validate::trial_stats`): (real, simulated).
fn measure(
    real: &[Trial],
    sim: &[Trial],
    lcfg: &LabelConfig,
) -> (Vec<TrialStats>, Vec<TrialStats>) {
    let pb = bar((real.len() + sim.len()) as u64, "measuring");
    let stats = |v: &[Trial]| -> Vec<TrialStats> {
        v.iter()
            .map(|t| {
                pb.inc(1);
                validate::trial_stats(t, lcfg)
            })
            .collect()
    };
    let rs = stats(real);
    let ss = stats(sim);
    pb.finish_and_clear();
    (rs, ss)
}

/// The share of a spectrum in 3–5 Hz, or "n/a".
fn band(s: &Option<Vec<f64>>) -> String {
    s.as_ref().map_or("n/a".into(), |s| {
        format!("{:.1}%", 100.0 * validate::band_3_5(s, PAPER_RATE_HZ))
    })
}

/// Mean spectra of d(t) before the drop (failures) and in the hold (successes), real and
/// simulated, each with the number of trials it averages.
struct Spectra {
    real_pre: Option<Vec<f64>>,
    real_pre_n: usize,
    sim_pre: Option<Vec<f64>>,
    sim_pre_n: usize,
    real_hold: Option<Vec<f64>>,
    real_hold_n: usize,
    sim_hold: Option<Vec<f64>>,
    sim_hold_n: usize,
    /// Bin frequencies, Hz.
    freqs: Vec<f64>,
}

impl Spectra {
    fn of(rs: &[TrialStats], ss: &[TrialStats]) -> Self {
        let spec = |v: &[TrialStats], pre: bool| {
            let s: Vec<&Vec<f64>> = v
                .iter()
                .filter_map(|s| {
                    if pre {
                        s.spectrum_pre_drop.as_ref()
                    } else {
                        s.spectrum_hold.as_ref()
                    }
                })
                .collect();
            (validate::mean_spectrum(&s), s.len())
        };
        let (real_pre, real_pre_n) = spec(rs, true);
        let (sim_pre, sim_pre_n) = spec(ss, true);
        let (real_hold, real_hold_n) = spec(rs, false);
        let (sim_hold, sim_hold_n) = spec(ss, false);
        let freqs = (0..=validate::SPECTRUM_WIN / 2)
            .map(|k| dsp::bin_hz(k, validate::SPECTRUM_WIN, PAPER_RATE_HZ))
            .collect();
        Spectra {
            real_pre,
            real_pre_n,
            sim_pre,
            sim_pre_n,
            real_hold,
            real_hold_n,
            sim_hold,
            sim_hold_n,
            freqs,
        }
    }

    /// The four spectra with their names and plot colours.
    fn series(&self) -> [(&Option<Vec<f64>>, &'static str, RGBColor); 4] {
        [
            (
                &self.real_pre,
                "real, 40 steps before drop",
                RGBColor(200, 0, 0),
            ),
            (
                &self.sim_pre,
                "sim, 40 steps before drop",
                RGBColor(255, 140, 120),
            ),
            (
                &self.real_hold,
                "real, hold (l1+5..l1+45)",
                RGBColor(0, 60, 200),
            ),
            (
                &self.sim_hold,
                "sim, hold (l1+5..l1+45)",
                RGBColor(120, 170, 255),
            ),
        ]
    }

    /// `img/sim-vs-real-spectra.png`.
    fn plot(&self, img: &Path) -> anyhow::Result<()> {
        let mut series = Vec::new();
        for (s, name, col) in self.series() {
            if let Some(s) = s {
                series.push((name.to_string(), s.clone(), col));
            }
        }
        plot::plot_spectra(
            "Relative power of d(t) = f(t) - f(t-1), 20-step rectangular STFT, contact channels",
            &self.freqs,
            &series,
            &img.join("sim-vs-real-spectra.png"),
        )?;
        Ok(())
    }
}

/// `img/sim-vs-real-trials.png`: the [`PAIR_REAL`] trials, each beside a simulated trial of
/// its outcome; returns the pairs shown ("real ↔ sim").
fn side_by_side(real: &[Trial], sim: &[Trial], img: &Path) -> anyhow::Result<Vec<String>> {
    let fails: Vec<&Trial> = sim
        .iter()
        .filter(|t| t.outcome == Outcome::Failure)
        .collect();
    let succ: Vec<&Trial> = sim
        .iter()
        .filter(|t| t.outcome == Outcome::Success && t.extra.contains_key("sim_redistribution"))
        .chain(sim.iter().filter(|t| t.outcome == Outcome::Success))
        .collect();
    let find = |id: &str| real.iter().find(|t| t.id == id);
    let mut pairs: Vec<(&Trial, &Trial)> = Vec::new();
    let mut used = Vec::new();
    for (k, id) in PAIR_REAL.iter().enumerate() {
        let Some(r) = find(id) else { continue };
        let s = if r.outcome == Outcome::Failure {
            fails.get(k)
        } else {
            succ.first()
        };
        if let Some(s) = s {
            pairs.push((r, s));
            used.push(format!("{} ↔ {}", r.id, s.id));
        }
    }
    if !pairs.is_empty() {
        plot::plot_pairs(&pairs, &img.join("sim-vs-real-trials.png"), Some(260))?;
    }
    Ok(used)
}

/// Examples of the set-ups without real data: a 40 Hz force drop and 40 suction trials.
struct OtherSetups {
    /// The first 40 Hz force trial drawn as a drop that failed.
    f40: Option<Trial>,
    /// Suction trials drawn, and how many detached.
    s_n: usize,
    s_drop: usize,
    /// Median pre-attach reading of the suction cups, counts.
    base_med: f64,
    /// The suction examples' sentence (empty without both examples).
    suction_rows: String,
}

impl OtherSetups {
    /// Draws them and writes `img/sim-force-40hz.png` and `img/sim-suction.png`.
    fn simulate(a: &Args, img: &Path) -> anyhow::Result<Self> {
        let cfg40 = ForceSimConfig::at_rate(40.0);
        let f40 = (0..200u64)
            .map(|i| force::simulate_trial(a.seed, i, Some(Intent::Drop), a.failure_share, &cfg40))
            .find(|t| t.outcome == Outcome::Failure);
        if let Some(t) = &f40 {
            plot::plot_trial(t, None, &img.join("sim-force-40hz.png"))?;
        }
        let scfg = SuctionSimConfig::default();
        let mut suction_rows = String::new();
        let mut s_fail = None;
        let mut s_deform = None;
        let (mut s_n, mut s_drop, mut s_base) = (0, 0, Vec::new());
        for i in 0..40u64 {
            let (hi, lo) = suction::simulate_trial(a.seed, i, None, 0.4, &scfg);
            s_n += 1;
            if hi.outcome == Outcome::Failure {
                s_drop += 1;
            }
            let g = hi.marks.grasp_start.unwrap_or(1).max(1);
            for c in 0..4 {
                s_base.push(hi.samples[c][..g].iter().map(|&x| x as f64).sum::<f64>() / g as f64);
            }
            if s_fail.is_none() && hi.outcome == Outcome::Failure {
                s_fail = Some((hi.clone(), lo.clone()));
            }
            if s_deform.is_none()
                && hi.outcome == Outcome::Success
                && hi.extra.contains_key("sim_deformation")
            {
                s_deform = Some(hi.clone());
            }
        }
        if let (Some((hi, lo)), Some(d)) = (&s_fail, &s_deform) {
            plot::plot_stack(&[hi, lo, d], &img.join("sim-suction.png"))?;
            let _ = writeln!(
                suction_rows,
                "Example failure `{}`: {}; drop at step {} (71 Hz) / {} (17.75 Hz). Example false-alarm case `{}`: {}.",
                hi.id,
                hi.extra.get("sim_leak").map_or("-", String::as_str),
                hi.drop_step.map_or("-".into(), |d| d.to_string()),
                lo.drop_step.map_or("-".into(), |d| d.to_string()),
                d.id,
                d.extra.get("sim_deformation").map_or("-", String::as_str),
            );
        }
        Ok(OtherSetups {
            f40,
            s_n,
            s_drop,
            base_med: dsp::median(&s_base).unwrap_or(0.0),
            suction_rows,
        })
    }
}

/// What the validation report says.
struct Validation<'v> {
    a: &'v Args,
    count: usize,
    data: &'v Path,
    real: &'v [Trial],
    sim: &'v [Trial],
    table: &'v str,
    spectra: &'v Spectra,
    used: &'v [String],
    others: &'v OtherSetups,
}

impl Validation<'_> {
    /// `simulator-validation.md`: its sections in order.
    fn report(&self) -> String {
        let mut r = String::new();
        self.data_section(&mut r);
        let _ = writeln!(r, "## Per-phase force levels and drop dynamics\n");
        let _ = writeln!(r, "Levels are of the sum of a trial's contact channels.\n");
        r.push_str(self.table);
        self.spectra_section(&mut r);
        let _ = writeln!(r, "## Side by side\n");
        let _ = writeln!(
            r,
            "Left real, right simulated (first 260 steps; marks: grasp green, lift orange, l2 purple, drop red): {}.\n",
            self.used.join("; ")
        );
        let _ = writeln!(r, "![side by side](img/sim-vs-real-trials.png)\n");
        self.other_setups_section(&mut r);
        let _ = writeln!(r, "\n## Known structural differences (by construction)\n");
        let _ = writeln!(
            r,
            "- The simulator's contact pads carry a smooth first-order grip; real pads show steps and plateaus from \
             the finger controller, and the real sum often jumps between pads during the lift.\n\
             - Real idle channels have sporadic readings from cross-talk; the simulator draws independent spikes.\n\
             - Real post-drop readings (fingers closing on each other) are imitated only on one pad, with probability 0.5.\n\
             - Everything at the sensor is in mN with a 12-bit ADC over 33 N; the real sensor's non-linear low range \
             (values like 9, 19, 29 mN) is not modelled."
        );
        r
    }

    /// Title, the command that generated the report, and the data compared.
    fn data_section(&self, r: &mut String) {
        let (a, count, real) = (self.a, self.count, self.real);
        let n_fail_real = real
            .iter()
            .filter(|t| t.outcome == Outcome::Failure)
            .count();
        let n_fail_sim = self
            .sim
            .iter()
            .filter(|t| t.outcome == Outcome::Failure)
            .count();
        let _ = writeln!(
            r,
            "# Simulator validation: force simulator vs real eagle-shoal trials\n"
        );
        let _ = writeln!(
            r,
            "Generated by `slipguard simulate --validate --seed {} --failure-share {}` (count {}). \
             Do not edit by hand: rerun the command. Interpretation: docs/simulator.md.\n",
            a.seed, a.failure_share, count
        );
        let _ = writeln!(r, "## Data\n");
        let _ = writeln!(
            r,
            "- Real: {} trials with contact from `{}` ({} failures); trials without any contact channel are left out.",
            real.len(),
            self.data
                .file_name()
                .map_or("data".into(), |s| s.to_string_lossy().into_owned()),
            n_fail_real
        );
        let _ = writeln!(
            r,
            "  Trials used: {}.",
            real.iter()
                .map(|t| format!("`{}`", t.id))
                .collect::<Vec<_>>()
                .join(", ")
        );
        let _ = writeln!(
            r,
            "- Simulated: {count} force trials at {PAPER_RATE_HZ} Hz, seed {}, {} ended in a drop ({} success).",
            a.seed,
            n_fail_sim,
            count - n_fail_sim
        );
        let _ = writeln!(
            r,
            "- Both sides are measured by the same code (`validate::trial_stats`) with the same contact detection \
             (≥ 500 mN for 3 steps) and, for failures, the drop step (real: detected; sim: ground truth).\n"
        );
    }

    /// The spectra: the 3–5 Hz shares, the mean spectra per bin, the plot.
    fn spectra_section(&self, r: &mut String) {
        let s = self.spectra;
        let _ = writeln!(r, "\n## Spectra 0–8.35 Hz\n");
        let _ = writeln!(
            r,
            "Mean relative power of the first difference d(t) over 20-step rectangular windows (the paper's STFT), \
             contact channels, bins of 0.835 Hz; DC excluded. Pre-drop: the 40 steps before the drop (failures); \
             hold: lift start + 5 to + 45 (successes).\n"
        );
        let _ = writeln!(
            r,
            "| window | real: trials, share 3–5 Hz | sim: trials, share 3–5 Hz |"
        );
        let _ = writeln!(r, "|---|---|---|");
        let _ = writeln!(
            r,
            "| 40 steps before drop | {}, {} | {}, {} |",
            s.real_pre_n,
            band(&s.real_pre),
            s.sim_pre_n,
            band(&s.sim_pre)
        );
        let _ = writeln!(
            r,
            "| hold | {}, {} | {}, {} |",
            s.real_hold_n,
            band(&s.real_hold),
            s.sim_hold_n,
            band(&s.sim_hold)
        );
        let _ = writeln!(
            r,
            "\n| Hz | {} |",
            s.freqs
                .iter()
                .map(|f| format!("{f:.2}"))
                .collect::<Vec<_>>()
                .join(" | ")
        );
        let _ = writeln!(r, "|---|{}", "---|".repeat(s.freqs.len()));
        for (v, name, _) in s.series() {
            if let Some(v) = v {
                let _ = writeln!(
                    r,
                    "| {name} | {} |",
                    v.iter()
                        .map(|v| format!("{v:.3}"))
                        .collect::<Vec<_>>()
                        .join(" | ")
                );
            }
        }
        let _ = writeln!(r, "\n![spectra](img/sim-vs-real-spectra.png)\n");
    }

    /// The 40 Hz force and suction examples.
    fn other_setups_section(&self, r: &mut String) {
        let o = self.others;
        let _ = writeln!(
            r,
            "## Other sensor set-ups (no real data to compare with)\n"
        );
        if let Some(t) = &o.f40 {
            let _ = writeln!(
                r,
                "- 40 Hz force: `{}` ({} steps), slip onset step {:?}, drop step {:?}: ![40 Hz](img/sim-force-40hz.png)",
                t.id,
                t.n_steps(),
                t.slip_onset_step,
                t.drop_step
            );
        }
        let _ = writeln!(
            r,
            "- Suction (4 cups, 71 Hz and 17.75 Hz): {} of {} trials with failure share 0.4 detached; \
             median pre-attach reading {:.0} counts (target ≈ 6,400). {}\n  ![suction](img/sim-suction.png)",
            o.s_drop, o.s_n, o.base_med, o.suction_rows
        );
    }
}
