//! PNG plots (plotters, bitmap backend) of trials, sim-vs-real pairs and spectra.

use std::path::Path;

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

/// Checks that a PNG can be written at `path` (its folder exists, it may be created) before
/// anything is drawn, so that the error names the path and the cause once, instead of the
/// drawing backend's nested error.
pub fn writable(path: &Path) -> Result<&Path> {
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

/// Draw one trial into an area: contact channels, their sum (black), marks as
/// vertical lines (grasp green, lift orange, l2 purple, drop red), and the
/// unstable label region shaded red.
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
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d(0f32..n as f32, 0f32..ymax)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc(t.unit.to_string())
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(|e| e.to_string())?;
    if let Some(l) = labels
        && let Some(from) = l.unstable_from
    {
        let end = (l.seq_start + l.seq_len).min(n) as f32;
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(from as f32, 0.0), (end, ymax)],
                RED.mix(0.12).filled(),
            )))
            .map_err(|e| e.to_string())?;
    }
    for (k, &c) in chans.iter().enumerate() {
        let col = PALETTE[k % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                (0..n).map(|i| (i as f32, t.samples[c][i])),
                col.stroke_width(1),
            ))
            .map_err(|e| e.to_string())?
            .label(t.channel_names[c].clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], col));
    }
    chart
        .draw_series(LineSeries::new(
            (0..n).map(|i| (i as f32, sum[i])),
            BLACK.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?
        .label("sum")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 14, y)], BLACK));
    let marks = [
        (t.marks.grasp_start, RGBColor(0, 150, 0), "grasp"),
        (t.marks.lift_start, RGBColor(230, 140, 0), "lift"),
        (t.marks.open_start, RGBColor(130, 60, 170), "l2"),
        (t.drop_step, RGBColor(220, 0, 0), "drop"),
    ];
    for (m, col, name) in marks {
        if let Some(m) = m.filter(|&m| m < n) {
            chart
                .draw_series(DashedLineSeries::new(
                    [(m as f32, 0.0), (m as f32, ymax)],
                    6,
                    4,
                    col.stroke_width(2),
                ))
                .map_err(|e| e.to_string())?
                .label(format!("{name} {m}"))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], col.stroke_width(2)));
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font(("sans-serif", 11))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| e.to_string())?;
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
    let root = BitMapBackend::new(writable(path)?, (1400, h.max(330))).into_drawing_area();
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

/// Spectra: one line per (name, values, colour) against `freqs`.
pub fn plot_spectra(
    title: &str,
    freqs: &[f64],
    series: &[(String, Vec<f64>, RGBColor)],
    path: &Path,
) -> Result<()> {
    let root = BitMapBackend::new(writable(path)?, (900, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(path, e))?;
    let ymax = series
        .iter()
        .flat_map(|s| s.1.iter().copied())
        .fold(1e-9f64, f64::max)
        * 1.1;
    let xmax = freqs.last().copied().unwrap_or(8.35);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..xmax, 0f64..ymax)
        .map_err(|e| perr(path, e))?;
    chart
        .configure_mesh()
        .x_desc("Hz")
        .y_desc("share of power (DC excluded)")
        .draw()
        .map_err(|e| perr(path, e))?;
    for (name, v, col) in series {
        let col = *col;
        chart
            .draw_series(LineSeries::new(
                freqs.iter().copied().zip(v.iter().copied()),
                col.stroke_width(2),
            ))
            .map_err(|e| perr(path, e))?
            .label(name.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], col.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .draw()
        .map_err(|e| perr(path, e))?;
    root.present().map_err(|e| perr(path, e))
}

/// All channels of trials stacked vertically (for suction: 71 Hz over 17.75 Hz).
pub fn plot_stack(trials: &[&Trial], path: &Path) -> Result<()> {
    let root = BitMapBackend::new(writable(path)?, (1100, 330 * trials.len().max(1) as u32))
        .into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(path, e))?;
    let cells = root.split_evenly((trials.len().max(1), 1));
    for (t, area) in trials.iter().zip(&cells) {
        let n = t.n_steps();
        let (lo, hi) = t
            .samples
            .iter()
            .flatten()
            .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!("{} ({}, {} Hz)", t.id, t.outcome, t.rate_hz),
                ("sans-serif", 15),
            )
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(0f32..n as f32, (lo - 500.0)..(hi + 500.0))
            .map_err(|e| perr(path, e))?;
        chart
            .configure_mesh()
            .x_desc("step")
            .y_desc(t.unit.to_string())
            .draw()
            .map_err(|e| perr(path, e))?;
        for c in 0..t.n_channels() {
            let col = PALETTE[c % PALETTE.len()];
            chart
                .draw_series(LineSeries::new(
                    (0..n).map(|i| (i as f32, t.samples[c][i])),
                    col.stroke_width(1),
                ))
                .map_err(|e| perr(path, e))?
                .label(t.channel_names[c].clone())
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], col));
        }
        let marks = [
            (t.marks.grasp_start, RGBColor(0, 150, 0)),
            (t.marks.lift_start, RGBColor(230, 140, 0)),
            (t.marks.open_start, RGBColor(130, 60, 170)),
            (t.drop_step, RGBColor(220, 0, 0)),
        ];
        for (m, col) in marks {
            if let Some(m) = m {
                chart
                    .draw_series(DashedLineSeries::new(
                        [(m as f32, lo - 500.0), (m as f32, hi + 500.0)],
                        6,
                        4,
                        col.stroke_width(2),
                    ))
                    .map_err(|e| perr(path, e))?;
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|e| perr(path, e))?;
    }
    root.present().map_err(|e| perr(path, e))
}

/// A Fig. 8-style chart: x in steps, y from -0.05 to 1.15 (1 = stable, 0 = unstable).
pub type Fig8Chart<'a, DB> = ChartContext<
    'a,
    DB,
    Cartesian2d<plotters::coord::types::RangedCoordf32, plotters::coord::types::RangedCoordf32>,
>;

/// The paper's Fig. 8 phase marks — grasp (green dotted), lift (yellow dotted), drop (red
/// dash-dot) — as vertical lines with legend entries, then the legend itself. Shared by every
/// Fig. 8 plot ([`plot_prediction`], `replay::plot_fig8`).
pub fn draw_fig8_marks<'a, DB: DrawingBackend + 'a>(
    chart: &mut Fig8Chart<'a, DB>,
    n: usize,
    grasp: Option<usize>,
    lift: Option<usize>,
    drop: Option<usize>,
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let marks = [
        (grasp, RGBColor(0, 160, 0), "grasp", 2, 3),
        (lift, RGBColor(230, 190, 0), "lift", 2, 3),
        (drop, RGBColor(220, 0, 0), "drop", 10, 4),
    ];
    for (m, col, name, dash, gap) in marks {
        if let Some(m) = m.filter(|&m| m < n) {
            chart
                .draw_series(DashedLineSeries::new(
                    [(m as f32, -0.05), (m as f32, 1.15)],
                    dash,
                    gap,
                    col.stroke_width(2),
                ))?
                .label(format!("{name} {m}"))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], col.stroke_width(2)));
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font(("sans-serif", 11))
        .position(SeriesLabelPosition::LowerLeft)
        .draw()
}

/// Fig. 8 of the paper for one sequence: normalised force (thin blue), label (red dashed bold),
/// prediction (blue bold), 1 = stable and 0 = unstable as in the paper, with grasp (green
/// dotted), lift (yellow dotted) and drop (red dash-dot) marks.
pub fn plot_prediction(s: &Sequence, pred: &[Stability], title: &str, path: &Path) -> Result<()> {
    draw_prediction(s, pred, title, path).map_err(|e| perr(path, e))
}

fn draw_prediction(
    s: &Sequence,
    pred: &[Stability],
    title: &str,
    path: &Path,
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d)?;
    }
    let root = BitMapBackend::new(writable(path)?, (900, 420)).into_drawing_area();
    root.fill(&WHITE)?;
    let n = s.cs.samples.len();
    let max = s.cs.samples.iter().copied().fold(f32::MIN, f32::max);
    let min = s.cs.samples.iter().copied().fold(f32::MAX, f32::min);
    let span = (max - min).max(1e-6);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(45)
        .build_cartesian_2d(0f32..n as f32, -0.05f32..1.15f32)?;
    chart
        .configure_mesh()
        .x_desc(format!("step ({} Hz)", s.rate_hz))
        .y_desc("1 = stable, 0 = unstable")
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    let blue = RGBColor(31, 119, 180);
    chart
        .draw_series(LineSeries::new(
            (0..n).map(|i| (i as f32, (s.cs.samples[i] - min) / span)),
            blue.stroke_width(1),
        ))?
        .label("normalised force")
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], blue));
    let stable = |v: Stability| if v.is_unstable() { 0.0 } else { 1.0 };
    chart
        .draw_series(DashedLineSeries::new(
            (0..n).map(|i| (i as f32, stable(s.cs.labels[i]) + 0.02)),
            8,
            5,
            RED.stroke_width(3),
        ))?
        .label("label")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 14, y)], RED.stroke_width(3)));
    chart
        .draw_series(LineSeries::new(
            (0..n).map(|i| (i as f32, stable(pred[i]))),
            RGBColor(0, 40, 160).stroke_width(3),
        ))?
        .label("prediction")
        .legend(|(x, y)| {
            PathElement::new([(x, y), (x + 14, y)], RGBColor(0, 40, 160).stroke_width(3))
        });
    draw_fig8_marks(&mut chart, n, Some(0), s.lift, s.cs.drop_index)?;
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
