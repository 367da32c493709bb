//! Plotting chosen signals against time, as SVG or PNG.

use super::{Results, ResultsError};
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

/// The font used for all text: DejaVu Sans Mono, embedded (see `assets/DejaVu-LICENSE.txt`),
/// so plotting needs no system font library.
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSansMono.ttf");

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        for style in [FontStyle::Normal, FontStyle::Bold] {
            let _ = plotters::style::register_font("sans-serif", style, FONT);
        }
    });
}

/// Plots `signals` (column names) of `results` against time into `out`; the format follows
/// the extension (`.svg` or `.png`). `size` is in pixels.
pub fn plot_signals(
    results: &Results,
    signals: &[&str],
    out: &Path,
    size: (u32, u32),
) -> Result<(), ResultsError> {
    plot_signals_with(results, signals, out, size, &PlotLabels::default())
}

/// Axis labels and title of a plot.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotLabels {
    /// Label of the x axis (the results' first column).
    pub x: String,
    /// Label of the y axis (empty: none).
    pub y: String,
    /// Title above the chart (empty: none).
    pub title: String,
}

impl Default for PlotLabels {
    fn default() -> Self {
        PlotLabels {
            x: "time [s]".into(),
            y: String::new(),
            title: String::new(),
        }
    }
}

/// [`plot_signals`] with axis labels and a title: the first column need not be time (a
/// gait cycle in percent, for example).
pub fn plot_signals_with(
    results: &Results,
    signals: &[&str],
    out: &Path,
    size: (u32, u32),
    labels: &PlotLabels,
) -> Result<(), ResultsError> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("svg") => draw(
            SVGBackend::new(out, size).into_drawing_area(),
            results,
            signals,
            labels,
        ),
        Some("png") => draw(
            BitMapBackend::new(out, size).into_drawing_area(),
            results,
            signals,
            labels,
        ),
        _ => Err(ResultsError::Plot(format!(
            "unknown plot format for '{}': use .svg or .png",
            out.display()
        ))),
    }
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    results: &Results,
    signals: &[&str],
    labels: &PlotLabels,
) -> Result<(), ResultsError>
where
    DB::ErrorType: 'static,
{
    register_font();
    let e = |x: &dyn std::fmt::Display| ResultsError::Plot(x.to_string());
    let times = results.times();
    let mut series = Vec::new();
    for s in signals {
        let col = results.column(s).ok_or_else(|| {
            ResultsError::UnknownSignal(s.to_string(), results.names().join(", "))
        })?;
        series.push((s.to_string(), col));
    }
    let (t0, t1) = match (times.first(), times.last()) {
        (Some(&a), Some(&b)) if b > a => (a, b),
        (Some(&a), _) => (a, a + 1.0),
        _ => (0.0, 1.0),
    };
    let finite = series
        .iter()
        .flat_map(|(_, c)| c.iter().copied())
        .filter(|v| v.is_finite());
    let (mut lo, mut hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
        (l.min(v), h.max(v))
    });
    if !lo.is_finite() {
        (lo, hi) = (0.0, 1.0);
    }
    if hi - lo < 1e-12 * (1.0 + lo.abs()) {
        lo -= 0.5;
        hi += 0.5;
    }
    let pad = (hi - lo) * 0.05;
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut builder = ChartBuilder::on(&root);
    if !labels.title.is_empty() {
        builder.caption(&labels.title, ("sans-serif", 18));
    }
    let mut chart = builder
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(t0..t1, (lo - pad)..(hi + pad))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc(labels.x.as_str())
        .y_desc(labels.y.as_str())
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|x| e(&x))?;
    for (k, (name, col)) in series.iter().enumerate() {
        let color = Palette99::pick(k).to_rgba();
        chart
            .draw_series(LineSeries::new(
                times
                    .iter()
                    .copied()
                    .zip(col.iter().copied())
                    .filter(|(_, v)| v.is_finite()),
                color.stroke_width(2),
            ))
            .map_err(|x| e(&x))?
            .label(name.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
