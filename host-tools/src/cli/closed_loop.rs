//! `slipguard closed-loop`: drop rate with prediction off vs on, over seeded trials of the
//! paper's four situations, per model.

use slipguard_core::units::Millihertz;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Parser;
use plotters::prelude::*;
use slipguard::replay::{default_models, shipped_blobs};
use slipguard_learn::closed_loop::{
    ControllerConfig, FlagSource, INFERENCE_S, Latency, Outcome, Scenario, Situation,
    min_grip_needed, run_trial, summarise,
};

use super::check;
use slipguard_app::profile::Profile;
use slipguard_core::decision::Q15;

#[derive(Debug, Parser)]
pub struct Args {
    /// Model blob(s) to compare (repeatable). Default: the shipped hand models,
    /// models/hand-force/*.bin (16.7 Hz) and models/hand-force-40hz/*.bin (40 Hz), else the
    /// golden untrained blob.
    #[arg(long)]
    pub model: Vec<PathBuf>,
    /// Trials per situation (≥ 1).
    #[arg(long, default_value_t = 40, value_parser = check::usize_in!(1..))]
    pub trials: usize,
    /// Seed of the scenarios.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Grip step per unstable frame, as a fraction of the initial grip (> 0).
    #[arg(long, default_value_t = 0.2, value_parser = check::positive)]
    pub step: f64,
    /// Also run a perfect detector (true load ratio ≥ 0.85) with the same latency, at each
    /// model's frame rate.
    #[arg(long)]
    pub oracle: bool,
    /// Also run the perfect detector this many frames late (repeatable, with --oracle): the best
    /// a detector that needs that long to see the slip could do.
    #[arg(long, requires = "oracle")]
    pub oracle_delay: Vec<usize>,
    /// Write closed-loop.md and one PNG per situation here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Threads (default: available cores; 1…1024).
    #[arg(long, value_parser = check::usize_in!(1..=1024))]
    pub threads: Option<usize>,
    /// Decision threshold on p(unstable) the controller sets after grasp start (set-threshold
    /// command), 0 < threshold < 1; default: the blob's.
    #[arg(long, value_parser = check::open_unit)]
    pub threshold: Option<f64>,
    /// The controller ignores flags for this long after grasp start (ms).
    #[arg(long, default_value_t = 0)]
    pub settle_ms: u32,
    /// After a raise, the controller ignores unstable frames for this long (ms) so that its
    /// step reaches the fingers before it steps again (0 = a step on every unstable frame).
    #[arg(long, default_value_t = 0)]
    pub hold_off_ms: u32,
    /// Consecutive unstable frames before the flag rises, with `--threshold` (1…255).
    #[arg(long, default_value_t = 1, requires = "threshold", value_parser = clap::value_parser!(u8).range(1..))]
    pub raise_after: u8,
    /// Consecutive stable frames before the flag clears, with `--threshold` (1…255).
    #[arg(long, default_value_t = 1, requires = "threshold", value_parser = clap::value_parser!(u8).range(1..))]
    pub clear_after: u8,
    /// Run a blob the firmware would refuse (does not parse, over the build's bounds, rate or
    /// unit not the hand profile's) after a warning, instead of stopping.
    #[arg(long)]
    pub allow_bad_model: bool,
    /// The hand-load rule beside the models, at each model's rate: its fraction of the recent
    /// peak (0 < f < 1; default: the pick on the real trials, docs/results.md).
    #[arg(long, default_value_t = 0.4, value_parser = check::open_unit)]
    pub rule_fraction: f64,
    /// The hand-load rule's peak window (ms; frames at each rate, rounded).
    #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u32).range(1..=60_000))]
    pub rule_window_ms: u32,
    /// Also run every model fused with the rule: the rule OR the model's hand flag while the
    /// hand load is below this fraction of its peak (0 < g ≤ 1; host-side fusion of the
    /// firmware's flags, `slipguard_core::decision::FusedHand`; not for a blob that carries
    /// its own hand rule, whose flags the firmware already fuses).
    #[arg(long, value_parser = check::unit)]
    pub fused_guard: Option<f64>,
    /// Leave the hand-load rule out.
    #[arg(long)]
    pub no_rule: bool,
    /// When a frame's flags reach the controller: `firmware` = as the firmware runs (modelled
    /// inference of a 16-channel frame, 10.7 ms, + 0.61 ms on the wire); `deadline` = the bound
    /// the protocol guarantees (one period + 0.61 ms).
    #[arg(long, value_enum, default_value_t = LatencyArg::Firmware)]
    pub latency: LatencyArg,
}

/// `--latency`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LatencyArg {
    /// Modelled inference time + wire time.
    Firmware,
    /// One period + wire time.
    Deadline,
}

struct Source {
    name: String,
    blob: Option<slipguard_core::blob::AlignedBlob>,
    /// `Some(delay in frames)`: the perfect detector.
    oracle: Option<usize>,
    /// Frame rate (mHz): the model's, for the oracle the rate it stands beside.
    rate_mhz: Millihertz,
    /// With a blob: fused with this rule and guard (Q0.15).
    fused: Option<slipguard_core::decision::FusedHand>,
    /// The hand-load rule with the model's input scale and contact gate at that rate.
    rule: Option<(
        slipguard_core::decision::LoadRule,
        slipguard_core::sample::InputScale,
        slipguard_core::decision::ContactConfig,
    )>,
}

impl Source {
    /// What the loop runs for this source.
    fn flag_source(&self) -> FlagSource<'_> {
        match (&self.blob, self.oracle, self.rule, self.fused) {
            (Some(b), _, Some((_, scale, contact)), Some(fused)) => FlagSource::Fused {
                blob: b.as_bytes(),
                fused,
                scale,
                contact,
            },
            (Some(b), _, _, _) => FlagSource::Model(b.as_bytes()),
            (None, Some(delay_frames), _, _) => FlagSource::Oracle { delay_frames },
            (None, None, Some((rule, scale, contact)), _) => FlagSource::LoadRule {
                rule,
                scale,
                contact,
            },
            _ => FlagSource::Off,
        }
    }
}

/// Every scenario in the loop, in parallel on `pool`, the outcomes in the scenarios' order.
/// Scenario i's sensor-noise seed is `seed ^ (i mod ⌈n/2⌉)`: fixed per scenario whatever the
/// thread count (the split of the scenarios over two threads the published reports ran with).
fn run_all(
    scenarios: &[Scenario],
    src: FlagSource<'_>,
    ctl: &ControllerConfig,
    seed: u64,
    pool: &rayon::ThreadPool,
) -> Vec<Outcome> {
    use rayon::prelude::*;
    let half = scenarios.len().div_ceil(2).max(1);
    pool.install(|| {
        scenarios
            .par_iter()
            .enumerate()
            .map(|(i, sc)| run_trial(sc, src, ctl, None, seed ^ (i % half) as u64))
            .collect()
    })
}

/// `slipguard closed-loop`: the flag sources, the controller, then per situation every source
/// on the same scenarios (a table row each, and a plot with `--out`).
pub fn run(a: Args) -> anyhow::Result<()> {
    let threads = a
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("starting the worker threads")?;
    let (sources, rates) = flag_sources(&a)?;
    let (ctl, decision) = controller(&a)?;
    let mut md = header(&a, &rates, decision);
    for sit in Situation::ALL {
        let scenarios: Vec<Scenario> = (0..a.trials as u64)
            .map(|i| Scenario::draw(a.seed, i, sit))
            .collect();
        let min: Vec<f64> = scenarios.iter().map(|s| min_grip_needed(s, &ctl)).collect();
        let results: Vec<(String, Vec<Outcome>)> = sources
            .iter()
            .map(|s| {
                let ctl = ControllerConfig {
                    rate_mhz: s.rate_mhz,
                    ..ctl
                };
                (
                    s.name.clone(),
                    run_all(&scenarios, s.flag_source(), &ctl, a.seed, &pool),
                )
            })
            .collect();
        situation_rows(&mut md, sit, &results, &min);
        if let Some(dir) = &a.out {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
            let png = dir.join(format!("closed-loop-{}.png", sit.name()));
            plot(&scenarios, &results, &min, sit, &png)?;
        }
        eprintln!("closed-loop: {} done", sit.name());
    }
    print!("{md}");
    if let Some(dir) = &a.out {
        let p = dir.join("closed-loop.md");
        std::fs::write(&p, &md).with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// The flag sources in the report's order: off, each model (and its host-fused copy with
/// `--fused-guard`), the load rule at each model rate, the oracles; and the model rates.
fn flag_sources(a: &Args) -> anyhow::Result<(Vec<Source>, Vec<Millihertz>)> {
    let models = if a.model.is_empty() {
        let mut v = default_models(&Profile::HAND);
        v.extend(shipped_blobs("hand-force-40hz"));
        v
    } else {
        a.model.clone()
    };
    let default_rate = Profile::HAND.default_rate_mhz();
    let mut sources = vec![Source {
        name: "off".into(),
        blob: None,
        oracle: None,
        rate_mhz: default_rate,
        rule: None,
        fused: None,
    }];
    let mut rates = Vec::new();
    let mut rule_sources = Vec::new();
    for m in &models {
        // A blob the firmware refuses runs only with --allow-bad-model (fault frames only).
        let (blob, cfg) = check::load_model("closed-loop", m, &Profile::HAND, a.allow_bad_model)?;
        let rate_mhz = cfg.map_or(default_rate, |c| c.sample_rate_mhz);
        if !rates.contains(&rate_mhz) {
            rates.push(rate_mhz);
            if let (false, Some(c)) = (a.no_rule, cfg.as_ref()) {
                let rule = slipguard_learn::load_rule::rule(
                    a.rule_fraction,
                    a.rule_window_ms as f64 / 1000.0,
                    1e6 / rate_mhz.0 as f64,
                );
                rule_sources.push(Source {
                    name: format!(
                        "load rule {} Hz (< {:.2} of the peak over {} frames)",
                        rate_mhz.hz(),
                        a.rule_fraction,
                        rule.window
                    ),
                    blob: None,
                    oracle: None,
                    rate_mhz,
                    fused: None,
                    rule: Some((
                        rule,
                        slipguard_core::sample::InputScale::of(c),
                        slipguard_core::decision::ContactConfig::of(c),
                    )),
                });
            }
        }
        let file = m.file_name().map_or(m.display().to_string(), |s| {
            s.to_string_lossy().into_owned()
        });
        // A blob with a hand rule (format v2): the firmware's hand flag is already fused.
        let hand_rule = cfg.as_ref().and_then(|c| c.hand_rule);
        sources.push(Source {
            name: match &hand_rule {
                Some(r) => format!("{file} (fused in the firmware: {r})"),
                None => file.clone(),
            },
            blob: Some(blob.clone()),
            oracle: None,
            rate_mhz,
            rule: None,
            fused: None,
        });
        if let (Some(g), Some(c), None) = (a.fused_guard, cfg.as_ref(), hand_rule) {
            let f = slipguard_learn::load_rule::fused(
                a.rule_fraction,
                g,
                a.rule_window_ms as f64 / 1000.0,
                1e6 / rate_mhz.0 as f64,
            );
            sources.push(Source {
                name: format!("{file} fused (rule OR flag under {g:.2}·peak)"),
                blob: Some(blob),
                oracle: None,
                rate_mhz,
                fused: Some(f),
                rule: Some((
                    f.strict,
                    slipguard_core::sample::InputScale::of(c),
                    slipguard_core::decision::ContactConfig::of(c),
                )),
            });
        }
    }
    sources.extend(rule_sources);
    if rates.is_empty() {
        rates.push(default_rate);
    }
    if a.oracle {
        for &rate_mhz in &rates {
            for delay in std::iter::once(0).chain(a.oracle_delay.iter().copied()) {
                let mut name = "oracle".to_string();
                if rates.len() > 1 {
                    name += &format!(" {} Hz", rate_mhz.hz());
                }
                if delay > 0 {
                    name += &format!(", {delay} frame{} late", if delay > 1 { "s" } else { "" });
                }
                sources.push(Source {
                    name,
                    blob: None,
                    oracle: Some(delay),
                    rate_mhz,
                    rule: None,
                    fused: None,
                });
            }
        }
    }
    Ok((sources, rates))
}

/// A controller-set decision (Q0.15 threshold, raise after, clear after) from `--threshold`.
type SetDecision = (u16, u8, u8);

/// The grip controller of the options, and the decision it sets after grasp start.
fn controller(a: &Args) -> anyhow::Result<(ControllerConfig, Option<SetDecision>)> {
    let decision = match a.threshold {
        Some(t) if t > 0.0 && t < 1.0 && a.raise_after >= 1 && a.clear_after >= 1 => Some((
            Q15::from_f64(t).header_threshold(),
            a.raise_after,
            a.clear_after,
        )),
        Some(t) => anyhow::bail!(
            "--threshold {t} must be in (0, 1) and --raise-after/--clear-after at least 1"
        ),
        None => None,
    };
    let ctl = ControllerConfig {
        step_fraction: a.step,
        rate_mhz: Profile::HAND.default_rate_mhz(),
        decision,
        settle_s: a.settle_ms as f64 / 1000.0,
        hold_off_s: a.hold_off_ms as f64 / 1000.0,
        latency: match a.latency {
            LatencyArg::Firmware => Latency::MODELLED,
            LatencyArg::Deadline => Latency::Deadline,
        },
    };
    Ok((ctl, decision))
}

/// The report's set-up lines and the table header.
fn header(a: &Args, rates: &[Millihertz], decision: Option<SetDecision>) -> String {
    let latency = match a.latency {
        LatencyArg::Firmware => format!(
            "latency {:.1} ms (modelled inference of a 16-channel frame) + 0.61 ms on the wire \
             after a frame's last sample",
            1000.0 * INFERENCE_S
        ),
        LatencyArg::Deadline => "latency one frame + 0.61 ms (the deadline bound)".to_string(),
    };
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Closed loop: {} trials per situation, seed {}, grip step {:.0} % of the initial grip, \
         frame rate {} Hz (each model's own), {latency}.\n",
        a.trials,
        a.seed,
        100.0 * a.step,
        rates
            .iter()
            .map(|r| format!("{}", (*r).hz()))
            .collect::<Vec<_>>()
            .join(" / ")
    );
    if let Some((t, r, c)) = decision {
        let _ = writeln!(
            md,
            "Decision set by the controller after grasp start (set-threshold command): p ≥ {:.3}, \
             raise after {r}, clear after {c} frames.\n",
            Q15(t as i16).to_f64()
        );
    }
    let _ = writeln!(
        md,
        "| situation | prediction | drops | prevented (of drops off) | grip increases / trial (before the lift) | final grip (median, N) | final / minimum needed (median) |"
    );
    let _ = writeln!(md, "|---|---|---:|---:|---:|---:|---:|");
    md
}

/// One situation's rows: every source against "off" (the first), then the minimum grip.
fn situation_rows(
    md: &mut String,
    sit: Situation,
    results: &[(String, Vec<Outcome>)],
    min: &[f64],
) {
    let off = &results[0].1;
    for (name, r) in results {
        let c = summarise(r, off, min);
        let _ = writeln!(
            md,
            "| {} | {} | {}/{} ({:.0} %) | {} | {:.1} ({:.1}) | {:.2} | {:.2} |",
            sit.name(),
            name,
            c.drops,
            c.n,
            100.0 * c.drops as f64 / c.n.max(1) as f64,
            if name == "off" {
                "—".to_string()
            } else {
                format!("{}/{}", c.prevented, c.drops_off)
            },
            c.mean_increases,
            c.mean_increases_before_lift,
            c.median_final_n,
            c.median_final_over_min
        );
    }
    let mut m = min.to_vec();
    m.sort_by(f64::total_cmp);
    let _ = writeln!(
        md,
        "| {} | minimum constant grip that holds | | | | {:.2} | 1.00 |",
        sit.name(),
        m[m.len() / 2]
    );
}

/// Force and grip over time for the first three trials of a situation: one panel per trial,
/// load (black), grip per prediction source (coloured), minimum grip needed (grey dashed),
/// grip raises (dots), drops (crosses).
fn plot(
    scenarios: &[Scenario],
    results: &[(String, Vec<Outcome>)],
    min: &[f64],
    sit: Situation,
    path: &Path,
) -> anyhow::Result<()> {
    const COLOURS: [RGBColor; 5] = [
        RGBColor(214, 39, 40),
        RGBColor(31, 119, 180),
        RGBColor(44, 160, 44),
        RGBColor(148, 103, 189),
        RGBColor(255, 127, 14),
    ];
    let rows = scenarios.len().min(3);
    let root = BitMapBackend::new(
        slipguard::plot::writable(path)?,
        (1100, 300 * rows.max(1) as u32),
    )
    .into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let cells = root.split_evenly((rows.max(1), 1));
    for (k, cell) in cells.iter().enumerate().take(rows) {
        use slipguard::plot::Key;
        let (area, legend) = slipguard::plot::split_legend(cell);
        let mut keys = Vec::new();
        let ymax = results
            .iter()
            .flat_map(|(_, r)| r[k].trace.iter().map(|p| p.grip.max(p.load).max(p.pads)))
            .fold(min[k], f64::max)
            * 1.1;
        let mut chart = ChartBuilder::on(&area)
            .caption(
                format!(
                    "{} trial {k}: m {:.2} kg, μ {:.2}, initial grip {:.2} N",
                    sit.name(),
                    scenarios[k].mass_kg,
                    scenarios[k].p.mu_s,
                    scenarios[k].initial_grip_n
                ),
                ("sans-serif", 15),
            )
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(0f64..slipguard_learn::closed_loop::DURATION_S, 0f64..ymax)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("s")
            .y_desc("N")
            .light_line_style(WHITE.mix(0.0))
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let e = |e: &dyn std::fmt::Display| anyhow::anyhow!("{e}");
        let off = &results[0].1[k];
        chart
            .draw_series(LineSeries::new(
                off.trace.iter().map(|p| (p.t, p.load)),
                BLACK.stroke_width(1),
            ))
            .map_err(|x| e(&x))?;
        keys.push(Key::solid("load (off)", BLACK, 1));
        let grey = RGBColor(128, 128, 128);
        chart
            .draw_series(DashedLineSeries::new(
                [
                    (0.0, min[k]),
                    (slipguard_learn::closed_loop::DURATION_S, min[k]),
                ],
                6,
                4,
                grey.stroke_width(1),
            ))
            .map_err(|x| e(&x))?;
        keys.push(Key::dashed("minimum grip needed", grey, 1, (6, 4)));
        for (j, (name, r)) in results.iter().enumerate() {
            let col = COLOURS[j % COLOURS.len()];
            let o = &r[k];
            chart
                .draw_series(LineSeries::new(
                    o.trace.iter().map(|p| (p.t, p.grip)),
                    col.stroke_width(2),
                ))
                .map_err(|x| e(&x))?;
            keys.push(Key::solid(
                format!("grip, {name}{}", if o.dropped { " (dropped)" } else { "" }),
                col,
                2,
            ));
            chart
                .draw_series(LineSeries::new(
                    o.trace.iter().map(|p| (p.t, p.pads)),
                    col.mix(0.45).stroke_width(1),
                ))
                .map_err(|x| e(&x))?;
            let at = |t: f64| o.trace.iter().find(|p| p.t >= t).map_or(0.0, |p| p.grip);
            chart
                .draw_series(
                    o.raise_times
                        .iter()
                        .map(|&t| Circle::new((t, at(t)), 3, col.filled())),
                )
                .map_err(|x| e(&x))?;
            if let Some(t) = o.t_drop {
                chart
                    .draw_series(std::iter::once(Cross::new(
                        (t, 0.03 * ymax),
                        7,
                        col.stroke_width(3),
                    )))
                    .map_err(|x| e(&x))?;
            }
        }
        keys.push(Key::solid("thin: pad force, same colour", grey, 1));
        keys.push(Key::solid("dots: flag raised; ×: drop", grey, 1));
        slipguard::plot::draw_keys(&legend, 30, &keys).map_err(|x| e(&x))?;
    }
    root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(())
}
