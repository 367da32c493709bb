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

/// The image format of `out` by its extension, `svg` or `png` (any case); any other is refused
/// ([`plot_signals`] draws nothing then). For checking an output before any work.
pub fn image_format(out: &Path) -> Result<&'static str, ResultsError> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("svg") => Ok("svg"),
        Some("png") => Ok("png"),
        _ => Err(ResultsError::Plot(format!(
            "unknown plot format for '{}': use .svg or .png",
            out.display()
        ))),
    }
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
    let ext = image_format(out)?;
    if !(1..=MAX_SIDE).contains(&size.0) || !(1..=MAX_SIDE).contains(&size.1) {
        return Err(ResultsError::Plot(format!(
            "an image of {} x {} pixels: each side must be 1 to {MAX_SIDE}",
            size.0, size.1
        )));
    }
    // Everything that can be refused is checked before a file is opened, and the image is
    // drawn into a file beside `out`, renamed into place once complete: a refused or failed
    // plot leaves an earlier image at `out` as it was.
    let chart = Chart::of(results, signals)?;
    let mut partial_name = out.file_stem().unwrap_or_default().to_os_string();
    partial_name.push(format!(".partial.{ext}"));
    let partial = out.with_file_name(partial_name);
    let drawn = if ext == "svg" {
        draw(
            SVGBackend::new(&partial, size).into_drawing_area(),
            &chart,
            labels,
        )
    } else {
        draw(
            BitMapBackend::new(&partial, size).into_drawing_area(),
            &chart,
            labels,
        )
    };
    let done = drawn.and_then(|()| {
        std::fs::rename(&partial, out).map_err(|source| ResultsError::Io {
            path: out.to_path_buf(),
            source,
        })
    });
    if done.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    done
}

/// The largest side of an image in pixels: a PNG's buffer (3 bytes a pixel) of 16384 x 16384
/// is 805 MB, and plotters' bitmap indexes overflow past 32 bits.
pub const MAX_SIDE: u32 = 16_384;

/// What a plot draws, checked: the series by name, the axes' ranges, finite.
struct Chart {
    times: Vec<f64>,
    series: Vec<(String, Vec<f64>)>,
    x: (f64, f64),
    y: (f64, f64),
}

impl Chart {
    fn of(results: &Results, signals: &[&str]) -> Result<Chart, ResultsError> {
        let times = results.times();
        let mut series = Vec::new();
        for s in signals {
            let col = results.column(s).ok_or_else(|| {
                ResultsError::UnknownSignal(s.to_string(), results.names().join(", "))
            })?;
            series.push((s.to_string(), col));
        }
        if times.is_empty() {
            return Err(ResultsError::Plot("no rows to plot".into()));
        }
        if times.iter().any(|t| !t.is_finite()) {
            return Err(ResultsError::Plot(format!(
                "the first column ({}) holds a value that is not finite",
                results.names().first().map_or("time", String::as_str)
            )));
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
        let (y0, y1) = (lo - pad, hi + pad);
        // Axes wider than a double (values near +-1.8e308) have no scale: plotters then
        // looped for ever looking for tick marks.
        if !((t1 - t0).is_finite() && (y1 - y0).is_finite()) {
            return Err(ResultsError::Plot(format!(
                "the axes span more than a double can hold (time {t0:e} to {t1:e}, values \
                 {lo:e} to {hi:e})"
            )));
        }
        Ok(Chart {
            times,
            series,
            x: (t0, t1),
            y: (y0, y1),
        })
    }
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    plot: &Chart,
    labels: &PlotLabels,
) -> Result<(), ResultsError>
where
    DB::ErrorType: 'static,
{
    register_font();
    let e = |x: &dyn std::fmt::Display| ResultsError::Plot(x.to_string());
    let (times, series) = (&plot.times, &plot.series);
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut builder = ChartBuilder::on(&root);
    if !labels.title.is_empty() {
        builder.caption(&labels.title, ("sans-serif", 18));
    }
    let mut chart = builder
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(plot.x.0..plot.x.1, plot.y.0..plot.y.1)
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
