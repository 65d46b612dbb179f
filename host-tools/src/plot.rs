//! PNG plots (plotters, bitmap backend) of trials, sim-vs-real pairs and spectra.
//!
//! Text is drawn in pure Rust (plotters' `ab_glyph` feature) with the bundled DejaVu Sans
//! (`host-tools/assets/fonts/`, license beside it): no fontconfig, no system font, no
//! `pkg-config` in any build. [`writable`], which every plot calls before drawing, registers it.

use std::path::Path;
use std::sync::Once;

use plotters::element::DashedPathElement;
use plotters::prelude::*;

use slipguard_data::error::{DataError, Result};
use slipguard_data::labels::TrialLabels;
use slipguard_data::trial::{Stability, Trial};
use slipguard_learn::evaluation::Sequence;

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(23, 190, 207),
];

/// DejaVu Sans 2.37 (Bitstream Vera license: `host-tools/assets/fonts/LICENSE.txt`).
const FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// The font families the plots name. All map to the bundled font.
pub const FONT_FAMILIES: [&str; 3] = ["sans-serif", "serif", "monospace"];

/// Registers the bundled font under every family the plots name (once per process). Plotters
/// looks fonts up by family name only in this table, never on the system.
pub fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        for family in FONT_FAMILIES {
            let parsed = plotters::style::register_font(family, FontStyle::Normal, FONT).is_ok();
            // The bytes are the bundled TrueType file, compiled in: it parses (tests draw it).
            assert!(parsed, "the bundled DejaVuSans.ttf does not parse");
        }
    });
}

/// Checks that a PNG can be written at `path` (its folder exists, it may be created) before
/// anything is drawn, so that the error names the path and the cause once, instead of the
/// drawing backend's nested error. Registers the bundled font ([`register_fonts`]).
pub fn writable(path: &Path) -> Result<&Path> {
    register_fonts();
    std::fs::File::create(path).map_err(|e| DataError::io(path, e))?;
    Ok(path)
}

fn perr(path: &Path, e: impl std::fmt::Display) -> DataError {
    DataError::Plot {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Channels to draw: contact channels, else the 3 with the largest maxima.
fn shown_channels(t: &Trial) -> Vec<usize> {
    let c = t.contact_channels();
    if !c.is_empty() {
        return c;
    }
    let mut idx: Vec<usize> = (0..t.n_channels()).collect();
    let max = |c: usize| t.samples[c].iter().copied().fold(0.0f32, f32::max);
    idx.sort_by(|&a, &b| max(b).total_cmp(&max(a)));
    idx.truncate(3);
    idx
}

/// The y-axis name of a trial's sensor.
fn trial_axis(t: &Trial) -> String {
    let sensor = match t.unit {
        slipguard_data::trial::Unit::MilliNewton => "force",
        slipguard_data::trial::Unit::Counts => "pressure",
        slipguard_data::trial::Unit::Other(_) => "sensor",
    };
    format!("{sensor} ({})", t.unit)
}

/// The phase marks of a trial drawn as vertical lines between `y0` and `y1` (grasp green,
/// lift orange, l2 purple dotted; drop red long dashes), returning their legend keys.
fn draw_trial_marks<DB: DrawingBackend>(
    chart: &mut ChartContext<
        '_,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf32, plotters::coord::types::RangedCoordf32>,
    >,
    t: &Trial,
    n: usize,
    (y0, y1): (f32, f32),
) -> std::result::Result<Vec<Key>, String> {
    let marks = [
        (t.marks.grasp_start, RGBColor(0, 150, 0), "grasp", (3, 3)),
        (t.marks.lift_start, RGBColor(230, 130, 0), "lift", (3, 3)),
        (
            t.marks.open_start,
            RGBColor(130, 60, 170),
            "l2 (open)",
            (3, 3),
        ),
        (t.drop_step, RGBColor(200, 0, 0), "drop", (12, 4)),
    ];
    let mut keys = Vec::new();
    for (m, col, name, (dash, gap)) in marks {
        if let Some(m) = m.filter(|&m| m < n) {
            let x = m as f32 / t.rate_hz;
            chart
                .draw_series(DashedLineSeries::new(
                    [(x, y0), (x, y1)],
                    dash,
                    gap,
                    col.stroke_width(2),
                ))
                .map_err(|e| e.to_string())?;
            keys.push(Key::dashed(
                format!("{name} at {x:.1} s"),
                col,
                2,
                (dash.min(8), gap),
            ));
        }
    }
    Ok(keys)
}

/// Draw one trial into an area: contact channels, their sum (black), marks as vertical
/// lines (grasp green, lift orange, l2 purple, drop red), the unstable label region shaded
/// red; x in seconds (a margin left of 0 so that a mark at 0 stands off the axis), the legend
/// in a column right of the plot.
fn draw_trial<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    t: &Trial,
    labels: Option<&TrialLabels>,
    title: &str,
    xmax: Option<usize>,
) -> std::result::Result<(), String> {
    let chans = shown_channels(t);
    let sum = t.sum_over(&chans);
    let n = xmax.unwrap_or(t.n_steps()).min(t.n_steps());
    let ymax = sum[..n].iter().copied().fold(1.0f32, f32::max) * 1.08;
    let sec = |i: usize| i as f32 / t.rate_hz;
    let (plot, legend) = split_legend(area);
    let mut chart = ChartBuilder::on(&plot)
        .caption(title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(64)
        .build_cartesian_2d(fig8_x_range(sec(n)), 0f32..ymax)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(format!("seconds ({} Hz, {n} steps)", t.rate_hz))
        .y_desc(trial_axis(t))
        .x_label_formatter(&|v| format!("{v:.0}"))
        .y_label_formatter(&|v| format!("{v:.0}"))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(|e| e.to_string())?;
    let mut keys = Vec::new();
    if let Some(l) = labels
        && let Some(from) = l.unstable_from
    {
        let end = (l.seq_start + l.seq_len).min(n);
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(sec(from), 0.0), (sec(end), ymax)],
                RED.mix(0.12).filled(),
            )))
            .map_err(|e| e.to_string())?;
        keys.push(Key::solid("labelled unstable", RGBColor(250, 215, 215), 8));
    }
    let many = chans.len() > 8;
    for (k, &c) in chans.iter().enumerate() {
        let col = PALETTE[k % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                (0..n).map(|i| (sec(i), t.samples[c][i])),
                col.stroke_width(1),
            ))
            .map_err(|e| e.to_string())?;
        if !many {
            keys.push(Key::solid(t.channel_names[c].clone(), col, 1));
        }
    }
    if many {
        keys.push(Key::solid(
            format!("{} channels", chans.len()),
            PALETTE[0],
            1,
        ));
    }
    chart
        .draw_series(LineSeries::new(
            (0..n).map(|i| (sec(i), sum[i])),
            BLACK.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?;
    keys.push(Key::solid("sum of these", BLACK, 2));
    keys.extend(draw_trial_marks(&mut chart, t, n, (0.0, ymax))?);
    draw_keys(&legend, 30, &keys).map_err(|e| e.to_string())?;
    Ok(())
}

/// One trial with its marks and labels.
pub fn plot_trial(t: &Trial, labels: Option<&TrialLabels>, path: &Path) -> Result<()> {
    let root = BitMapBackend::new(writable(path)?, (1100, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(path, e))?;
    let title = format!("{} ({}, {} Hz)", t.id, t.outcome, t.rate_hz);
    draw_trial(&root, t, labels, &title, None).map_err(|e| perr(path, e))?;
    root.present().map_err(|e| perr(path, e))
}

/// Rows of (left, right) trials side by side, e.g. real vs simulated.
pub fn plot_pairs(rows: &[(&Trial, &Trial)], path: &Path, xmax: Option<usize>) -> Result<()> {
    let h = 330 * rows.len() as u32;
    let root = BitMapBackend::new(writable(path)?, (1800, h.max(330))).into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(path, e))?;
    let cells = root.split_evenly((rows.len(), 2));
    for (i, (a, b)) in rows.iter().enumerate() {
        for (j, t) in [a, b].iter().enumerate() {
            let kind = if t.source.starts_with("slipguard simulate") {
                "sim"
            } else {
                "real"
            };
            let title = format!("{kind}: {} ({})", t.id, t.outcome);
            draw_trial(&cells[2 * i + j], t, None, &title, xmax).map_err(|e| perr(path, e))?;
        }
    }
    root.present().map_err(|e| perr(path, e))
}

/// Spectra: one line per (name, values, colour) against `freqs` (the DC bin, excluded from
/// the shares, is not drawn), the legend right of the plot.
pub fn plot_spectra(
    title: &str,
    freqs: &[f64],
    series: &[(String, Vec<f64>, RGBColor)],
    path: &Path,
) -> Result<()> {
    draw_spectra(title, freqs, series, path).map_err(|e| perr(path, e))
}

fn draw_spectra(
    title: &str,
    freqs: &[f64],
    series: &[(String, Vec<f64>, RGBColor)],
    path: &Path,
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    let root = BitMapBackend::new(writable(path)?, (1100, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let ymax = series
        .iter()
        .flat_map(|s| s.1.iter().copied())
        .fold(1e-9f64, f64::max)
        * 1.1;
    let xmax = freqs.last().copied().unwrap_or(8.35);
    let (plot, legend) = split_legend(&root);
    let mut chart = ChartBuilder::on(&plot)
        .caption(title, ("sans-serif", 17))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..xmax, 0f64..ymax)?;
    chart
        .configure_mesh()
        .x_desc("Hz")
        .y_desc("share of power (DC excluded)")
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    let mut keys = Vec::new();
    for (name, v, col) in series {
        chart.draw_series(LineSeries::new(
            freqs
                .iter()
                .copied()
                .zip(v.iter().copied())
                .filter(|&(f, _)| f > 0.0),
            col.stroke_width(2),
        ))?;
        keys.push(Key::solid(name.clone(), *col, 2));
    }
    draw_keys(&legend, 40, &keys)?;
    root.present()?;
    Ok(())
}

/// All channels of trials stacked vertically (for suction: 71 Hz over 17.75 Hz), x in seconds,
/// the legend right of each plot.
pub fn plot_stack(trials: &[&Trial], path: &Path) -> Result<()> {
    let root = BitMapBackend::new(writable(path)?, (1100, 330 * trials.len().max(1) as u32))
        .into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(path, e))?;
    let cells = root.split_evenly((trials.len().max(1), 1));
    for (t, area) in trials.iter().zip(&cells) {
        draw_stack(area, t).map_err(|e| perr(path, e))?;
    }
    root.present().map_err(|e| perr(path, e))
}

fn draw_stack<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    t: &Trial,
) -> std::result::Result<(), String> {
    let n = t.n_steps();
    let sec = |i: usize| i as f32 / t.rate_hz;
    let (lo, hi) = t
        .samples
        .iter()
        .flatten()
        .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    let pad = ((hi - lo) * 0.05).max(1.0);
    let (y0, y1) = (lo - pad, hi + pad);
    let (plot, legend) = split_legend(area);
    let mut chart = ChartBuilder::on(&plot)
        .caption(
            format!("{} ({}, {} Hz)", t.id, t.outcome, t.rate_hz),
            ("sans-serif", 15),
        )
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(64)
        .build_cartesian_2d(fig8_x_range(sec(n)), y0..y1)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(format!("seconds ({} Hz, {n} steps)", t.rate_hz))
        .y_desc(trial_axis(t))
        .x_label_formatter(&|v| format!("{v:.0}"))
        .y_label_formatter(&|v| format!("{v:.0}"))
        .draw()
        .map_err(|e| e.to_string())?;
    let mut keys = Vec::new();
    for c in 0..t.n_channels() {
        let col = PALETTE[c % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                (0..n).map(|i| (sec(i), t.samples[c][i])),
                col.stroke_width(1),
            ))
            .map_err(|e| e.to_string())?;
        keys.push(Key::solid(t.channel_names[c].clone(), col, 1));
    }
    keys.extend(draw_trial_marks(&mut chart, t, n, (y0, y1))?);
    draw_keys(&legend, 30, &keys).map_err(|e| e.to_string())
}

/// A Fig. 8-style chart: x in seconds, y from -0.08 to 1.2 (0 = stable, 1 = unstable, as the
/// firmware's flag).
pub type Fig8Chart<'a, DB> = ChartContext<
    'a,
    DB,
    Cartesian2d<plotters::coord::types::RangedCoordf32, plotters::coord::types::RangedCoordf32>,
>;

/// The label's colour in every Fig. 8 plot (purple: apart from the red drop and orange lift).
pub const LABEL_COLOR: RGBColor = RGBColor(140, 40, 170);

/// Bottom and top of a Fig. 8 chart's y range (0 = stable, 1 = unstable).
pub const FIG8_Y: (f32, f32) = (-0.08, 1.2);

/// The x range of a Fig. 8 chart of `seconds`: a margin on the left, so that a mark at 0 (the
/// contact onset) stands off the axis.
pub fn fig8_x_range(seconds: f32) -> std::ops::Range<f32> {
    let s = seconds.max(0.1);
    -0.03 * s..s * 1.01
}

/// One legend entry: a line sample (solid, or dashed with `dash` = (dash, gap) pixels) and
/// its text. Legends are drawn in their own column right of the plot ([`split_legend`],
/// [`draw_keys`]), never over the data.
#[derive(Debug, Clone)]
pub struct Key {
    pub label: String,
    pub color: RGBColor,
    pub width: u32,
    pub dash: Option<(u32, u32)>,
}

impl Key {
    pub fn solid(label: impl Into<String>, color: RGBColor, width: u32) -> Self {
        Self {
            label: label.into(),
            color,
            width,
            dash: None,
        }
    }

    pub fn dashed(label: impl Into<String>, color: RGBColor, width: u32, dash: (u32, u32)) -> Self {
        Self {
            dash: Some(dash),
            ..Self::solid(label, color, width)
        }
    }
}

/// Width of the legend column, pixels.
pub const LEGEND_WIDTH: u32 = 210;

/// Splits `area` into the plot (left) and its legend column (right, [`LEGEND_WIDTH`]).
pub fn split_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
) -> (
    DrawingArea<DB, plotters::coord::Shift>,
    DrawingArea<DB, plotters::coord::Shift>,
) {
    let (w, _) = area.dim_in_pixel();
    area.split_horizontally(w.saturating_sub(LEGEND_WIDTH))
}

/// Draws `keys` top-down in a legend column, from `top` pixels down.
pub fn draw_keys<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    top: i32,
    keys: &[Key],
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let font = ("sans-serif", 13).into_font();
    for (i, k) in keys.iter().enumerate() {
        let y = top + 8 + 19 * i as i32;
        let style = k.color.stroke_width(k.width);
        match k.dash {
            Some((d, g)) => {
                area.draw(&DashedPathElement::new(vec![(6, y), (34, y)], d, g, style))?
            }
            None => area.draw(&PathElement::new(vec![(6, y), (34, y)], style))?,
        }
        area.draw(&Text::new(k.label.clone(), (42, y - 7), font.clone()))?;
    }
    Ok(())
}

/// Title (first line) and a second line in grey above a plot: returns the area below.
pub fn draw_title<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    second: &str,
) -> std::result::Result<DrawingArea<DB, plotters::coord::Shift>, DrawingAreaErrorKind<DB::ErrorType>>
{
    let (head, body) = area.split_vertically(48);
    head.draw(&Text::new(
        title.to_string(),
        (10, 5),
        ("sans-serif", 17).into_font(),
    ))?;
    head.draw(&Text::new(
        second.to_string(),
        (10, 27),
        ("sans-serif", 15).into_font().color(&RGBColor(70, 70, 70)),
    ))?;
    Ok(body)
}

/// The paper's Fig. 8 phase marks — grasp (green dotted), lift (orange dotted), drop (red
/// long dashes) — as vertical lines at their time in seconds; returns their legend keys.
/// Shared by every Fig. 8 plot ([`plot_prediction`], `replay::plot_fig8`).
pub fn draw_fig8_marks<'a, DB: DrawingBackend + 'a>(
    chart: &mut Fig8Chart<'a, DB>,
    grasp: Option<f32>,
    lift: Option<f32>,
    drop: Option<f32>,
) -> std::result::Result<Vec<Key>, DrawingAreaErrorKind<DB::ErrorType>> {
    let marks = [
        (grasp, RGBColor(0, 150, 0), "grasp", (3, 3)),
        (lift, RGBColor(230, 130, 0), "lift", (3, 3)),
        (drop, RGBColor(200, 0, 0), "drop", (12, 4)),
    ];
    let mut keys = Vec::new();
    for (m, col, name, (dash, gap)) in marks {
        if let Some(m) = m {
            chart.draw_series(DashedLineSeries::new(
                [(m, FIG8_Y.0), (m, FIG8_Y.1)],
                dash,
                gap,
                col.stroke_width(2),
            ))?;
            // A sequence cut to a channel's contact onset clamps an earlier lift to its start.
            let at = if name == "lift" && m <= 0.0 {
                "at or before".to_string()
            } else {
                "at".to_string()
            };
            keys.push(Key::dashed(
                format!("{name} {at} {m:.1} s"),
                col,
                2,
                (dash.min(8), gap),
            ));
        }
    }
    Ok(keys)
}

/// What a flag stream did on a sequence, in words for a plot's title: failures "flag 0.8 s
/// before the drop: in time", "flag 0.3 s after the drop: late", "no flag: missed"; successes
/// "no flag: correct", "false alarm at 2.1 s". `flags[i]` is step `i`; `drop` the drop step.
pub fn flag_verdict(flags: &[bool], failure: bool, drop: Option<usize>, rate_hz: f32) -> String {
    let first = flags.iter().position(|&f| f);
    let secs = |steps: usize| steps as f32 / rate_hz;
    match (failure, drop, first) {
        (true, Some(d), Some(f)) if f < d => {
            format!(
                "failure, flag {:.2} s before the drop: in time",
                secs(d - f)
            )
        }
        (true, Some(d), Some(f)) if f == d => "failure, flag at the drop step: late".into(),
        (true, Some(d), Some(f)) => {
            format!("failure, flag {:.2} s after the drop: late", secs(f - d))
        }
        (true, _, None) => "failure, no flag: missed".into(),
        (true, None, Some(f)) => format!("failure (no drop found), flag at {:.1} s", secs(f)),
        (false, _, Some(f)) => format!("success, false alarm at {:.1} s: wrong", secs(f)),
        (false, _, None) => "success, no flag: correct".into(),
    }
}

/// The sensor a trace comes from, named as the y legend says it.
pub fn sensor_name(unit: slipguard_core::blob::InputUnit) -> &'static str {
    match unit {
        slipguard_core::blob::InputUnit::MilliNewton => "force",
        slipguard_core::blob::InputUnit::Counts => "pressure",
    }
}

/// Fig. 8 of the paper for one sequence, with the firmware's convention 1 = unstable (the
/// flag): the sensor trace scaled to 0–1 (thin grey), the label (orange, dashed, drawn slightly
/// above), the prediction (blue, solid), the drop shaded and the grasp / lift / drop marks; the
/// title's second line says the outcome and whether the flag came in time ([`flag_verdict`]).
/// Time runs in seconds from the sequence's start (the channel's contact onset).
pub fn plot_prediction(
    s: &Sequence,
    pred: &[Stability],
    unit: slipguard_core::blob::InputUnit,
    title: &str,
    path: &Path,
) -> Result<()> {
    draw_prediction(s, pred, unit, title, path).map_err(|e| perr(path, e))
}

fn draw_prediction(
    s: &Sequence,
    pred: &[Stability],
    unit: slipguard_core::blob::InputUnit,
    title: &str,
    path: &Path,
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    let root = BitMapBackend::new(writable(path)?, (1040, 440)).into_drawing_area();
    root.fill(&WHITE)?;
    let n = s.cs.samples.len();
    let rate = s.rate_hz;
    let t = |i: usize| i as f32 / rate;
    let max = s.cs.samples.iter().copied().fold(f32::MIN, f32::max);
    let min = s.cs.samples.iter().copied().fold(f32::MAX, f32::min);
    let span = (max - min).max(1e-6);
    let flags: Vec<bool> = pred.iter().map(|p| p.is_unstable()).collect();
    let verdict = flag_verdict(&flags, s.failure(), s.cs.drop_index, rate);
    let body = draw_title(&root, title, &verdict)?;
    let (plot, legend) = split_legend(&body);
    let mut chart = ChartBuilder::on(&plot)
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(fig8_x_range(t(n)), FIG8_Y.0..FIG8_Y.1)?;
    let trace = sensor_name(unit);
    chart
        .configure_mesh()
        .x_desc(format!(
            "seconds from the sequence's start (the channel's grasp or contact onset; {rate} Hz, {n} steps)"
        ))
        .y_desc("flag: 1 = unstable, 0 = stable")
        .x_label_formatter(&|v| format!("{v:.1}"))
        .y_labels(3)
        .y_label_formatter(&|v| format!("{v:.1}"))
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    let mut keys = Vec::new();
    if let Some(d) = s.cs.drop_index.filter(|&d| d < n) {
        chart.draw_series(std::iter::once(Rectangle::new(
            [(t(d), FIG8_Y.0), (t(n), FIG8_Y.1)],
            RGBColor(200, 0, 0).mix(0.07).filled(),
        )))?;
    }
    let grey = RGBColor(120, 120, 120);
    chart.draw_series(LineSeries::new(
        (0..n).map(|i| (t(i), (s.cs.samples[i] - min) / span)),
        grey.stroke_width(1),
    ))?;
    keys.push(Key::solid(format!("{trace}, scaled 0–1"), grey, 1));
    let code = |v: Stability| if v.is_unstable() { 1.0 } else { 0.0 };
    // The label runs 0.03 above the prediction so that both stay visible where they agree.
    chart.draw_series(DashedLineSeries::new(
        (0..n).map(|i| (t(i), code(s.cs.labels[i]) + 0.03)),
        9,
        5,
        LABEL_COLOR.stroke_width(3),
    ))?;
    keys.push(Key::dashed("label (paper's rule)", LABEL_COLOR, 3, (6, 4)));
    let blue = RGBColor(0, 60, 200);
    chart.draw_series(LineSeries::new(
        (0..n.min(pred.len())).map(|i| (t(i), code(pred[i]))),
        blue.stroke_width(3),
    ))?;
    keys.push(Key::solid("prediction (flag)", blue, 3));
    keys.extend(draw_fig8_marks(
        &mut chart,
        Some(0.0),
        s.lift.filter(|&l| l < n).map(t),
        s.cs.drop_index.filter(|&d| d < n).map(t),
    )?);
    draw_keys(&legend, 8, &keys)?;
    root.present()?;
    Ok(())
}

/// The operating curve of a model: detected failures against successes with a false alarm
/// (hand level, armed window) as the threshold moves, one line per raise_after, the model's
/// own decision marked.
pub fn plot_operating_curve(
    curve: &[slipguard_learn::product::CurvePoint],
    shipped: Option<&slipguard_learn::product::CurvePoint>,
    title: &str,
    path: &Path,
) -> Result<()> {
    draw_operating_curve(curve, shipped, None, title, path).map_err(|e| perr(path, e))
}

/// [`plot_operating_curve`] with the hand-load rule beside it: its curve over the fractions
/// (grey) and its held-out point (a diamond).
pub fn plot_operating_curve_with_rule(
    curve: &[slipguard_learn::product::CurvePoint],
    shipped: Option<&slipguard_learn::product::CurvePoint>,
    rule: Option<(
        &[slipguard_learn::product::CurvePoint],
        &slipguard_learn::product::CurvePoint,
    )>,
    title: &str,
    path: &Path,
) -> Result<()> {
    draw_operating_curve(curve, shipped, rule, title, path).map_err(|e| perr(path, e))
}

fn draw_operating_curve(
    curve: &[slipguard_learn::product::CurvePoint],
    shipped: Option<&slipguard_learn::product::CurvePoint>,
    rule: Option<(
        &[slipguard_learn::product::CurvePoint],
        &slipguard_learn::product::CurvePoint,
    )>,
    title: &str,
    path: &Path,
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    let root = BitMapBackend::new(writable(path)?, (640, 560)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 15))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(-0.02f64..1.02f64, -0.02f64..1.05f64)?;
    chart
        .configure_mesh()
        .x_desc("successes with a false alarm in the armed window (share)")
        .y_desc("failures detected before the drop (share)")
        .draw()?;
    let mut raises: Vec<u8> = curve.iter().map(|p| p.raise_after).collect();
    raises.sort_unstable();
    raises.dedup();
    for (i, r) in raises.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        let pts: Vec<(f64, f64)> = curve
            .iter()
            .filter(|p| p.raise_after == *r)
            .map(|p| (p.false_alarm_grasp_rate, p.detected_rate))
            .collect();
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))?
            .label(format!("raise after {r}"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], c.stroke_width(2)));
        chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))?;
    }
    if let Some((rc, rp)) = rule {
        let grey = RGBColor(120, 120, 120);
        let pts: Vec<(f64, f64)> = rc
            .iter()
            .map(|p| (p.false_alarm_grasp_rate, p.detected_rate))
            .collect();
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), grey.stroke_width(2)))?
            .label("load rule, fractions 0.2–0.8 (0.6 s window)")
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], grey.stroke_width(2)));
        let p = (rp.false_alarm_grasp_rate, rp.detected_rate);
        let diamond = |(x, y): (f64, f64)| {
            EmptyElement::at((x, y))
                + Polygon::new(
                    vec![(0, -8), (8, 0), (0, 8), (-8, 0)],
                    RGBColor(200, 0, 0).filled(),
                )
        };
        chart
            .draw_series(std::iter::once(diamond(p)))?
            .label("load rule, held out (parameters picked on training trials)")
            .legend(|(x, y)| Circle::new((x + 7, y), 4, RGBColor(200, 0, 0).filled()));
    }
    if let Some(s) = shipped {
        let p = (s.false_alarm_grasp_rate, s.detected_rate);
        chart
            .draw_series(std::iter::once(Cross::new(p, 9, BLACK.stroke_width(3))))?
            .label(format!(
                "model's decision (p ≥ {:.2}, {} steps)",
                s.threshold, s.raise_after
            ))
            .legend(|(x, y)| Cross::new((x + 7, y), 5, BLACK.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 11))
        .position(SeriesLabelPosition::LowerRight)
        .draw()?;
    root.present()?;
    Ok(())
}
