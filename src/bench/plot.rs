//! PNG line plots of benchmark sweeps (plotters, bitmap backend, a system TrueType font).
//! The panels are plain data; drawing them needs the cargo feature `plots`.

use crate::error::{Error, Result};
#[cfg(feature = "plots")]
use plotters::prelude::*;
use std::path::Path;
#[cfg(feature = "plots")]
use std::sync::OnceLock;

#[cfg(feature = "plots")]
/// TrueType fonts tried in order (Debian: fonts-dejavu-core, installed by tools/setup.sh).
const FONT_PATHS: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
];

#[cfg(feature = "plots")]
fn ensure_font() -> Result<()> {
    static FONT: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        // VKSHADE_FONT first: a machine without the Debian font (tools/bench-gpu.sh carries
        // one there).
        let env = std::env::var("VKSHADE_FONT").ok();
        let bytes = env
            .iter()
            .map(String::as_str)
            .chain(FONT_PATHS.iter().copied())
            .find_map(|p| std::fs::read(p).ok())
            .ok_or_else(|| {
                format!(
                    "plots need a TrueType font; none found at {} (apt-get install fonts-dejavu-core)",
                    FONT_PATHS.join(", ")
                )
            })?;
        // Registered once for the life of the process, as plotters requires.
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .map_err(|_| "the font file is not a valid TrueType font".to_string())
    })
    .clone()
    .map_err(Error::InvalidArgument)
}

/// Whether this build can draw plots: an error naming the feature `plots` when not, so a
/// command can refuse `--plot` before a long run.
pub fn ensure_available() -> Result<()> {
    if cfg!(feature = "plots") {
        Ok(())
    } else {
        Err(Error::feature("drawing plots (--plot)", "plots"))
    }
}

/// Draws `panels` into a PNG: compiled out (feature `plots`), always an error naming it.
#[cfg(not(feature = "plots"))]
pub fn draw(path: &Path, _panels: &[Panel]) -> Result<()> {
    Err(Error::feature(
        format!("drawing the plot {}", path.display()),
        "plots",
    ))
}

/// One line of a plot.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// One panel: a titled chart of several series.
#[derive(Clone, Debug)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<Series>,
}

#[cfg(feature = "plots")]
fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let v: Vec<f64> = values
        .filter(|v| v.is_finite() && (!log || *v > 0.0))
        .collect();
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !lo.is_finite() || !hi.is_finite() {
        return if log { (1.0, 10.0) } else { (0.0, 1.0) };
    }
    if log {
        (lo / 1.25, hi * 1.25)
    } else {
        let pad = ((hi - lo) * 0.08).max(hi.abs() * 0.05).max(1e-12);
        (
            (lo - pad).min(if lo >= 0.0 { 0.0 } else { lo - pad }),
            hi + pad,
        )
    }
}

#[cfg(feature = "plots")]
/// Draws `panels` side by side into a PNG at `path` (written atomically).
pub fn draw(path: &Path, panels: &[Panel]) -> Result<()> {
    ensure_font()?;
    let width = 640 * panels.len().max(1) as u32;
    let height = 480u32;
    let mut pixels = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| Error::InvalidArgument(format!("plot: {e}"));
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let areas = root.split_evenly((1, panels.len().max(1)));
        for (panel, area) in panels.iter().zip(areas.iter()) {
            draw_panel(panel, area).map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    let img = image::RgbImage::from_raw(width, height, pixels)
        .ok_or_else(|| Error::InvalidArgument("plot buffer size mismatch".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| Error::InvalidArgument(format!("PNG encoding failed: {e}")))?;
    crate::io::write_atomic(path, &png)
}

#[cfg(feature = "plots")]
type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

#[cfg(feature = "plots")]
fn draw_panel(
    panel: &Panel,
    area: &Area<'_>,
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    let (x0, x1) = range(
        panel
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.0)),
        panel.log_x,
    );
    let (y0, y1) = range(
        panel
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.1)),
        panel.log_y,
    );
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(&panel.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60);
    macro_rules! finish {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(panel.x_label.as_str())
                .y_desc(panel.y_label.as_str())
                .label_style(("sans-serif", 13))
                .draw()?;
            for (i, s) in panel.series.iter().enumerate() {
                let color = Palette99::pick(i).to_rgba();
                let pts: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .filter(|(x, y)| x.is_finite() && y.is_finite())
                    .collect();
                // An empty series keeps its colour slot (so a series keeps its colour
                // across panels that lack another) but draws nothing and takes no legend.
                if pts.is_empty() {
                    continue;
                }
                chart
                    .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))?
                    .label(s.name.as_str())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                    });
                chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))?;
            }
            if panel.series.len() > 1 || panel.series.iter().any(|s| !s.name.is_empty()) {
                chart
                    .configure_series_labels()
                    .position(legend_corner(panel, (x0, x1), (y0, y1)))
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 13))
                    .draw()?;
            }
        }};
    }
    // Log axes are labelled at 1, 2 and 5 times the powers of ten inside their range: a
    // range within one decade (e.g. errors from 0.019 to 0.08) would otherwise get no label.
    let lx = || (x0..x1).log_scale().with_key_points(log_key_points(x0, x1));
    let ly = || (y0..y1).log_scale().with_key_points(log_key_points(y0, y1));
    match (panel.log_x, panel.log_y) {
        (false, false) => finish!(builder.build_cartesian_2d(x0..x1, y0..y1)?),
        (true, false) => finish!(builder.build_cartesian_2d(lx(), y0..y1)?),
        (false, true) => finish!(builder.build_cartesian_2d(x0..x1, ly())?),
        (true, true) => finish!(builder.build_cartesian_2d(lx(), ly())?),
    }
    Ok(())
}

/// Where the legend goes: the upper corner (left unless the right one is emptier) with
/// fewer of the panel's points under it, in the axes' own (linear or log) coordinates, the
/// legend taken to cover the top 40% and the outer 45% of the width.
#[cfg(feature = "plots")]
fn legend_corner(panel: &Panel, x: (f64, f64), y: (f64, f64)) -> SeriesLabelPosition {
    let unit = |v: f64, (lo, hi): (f64, f64), log: bool| {
        if log {
            (v.ln() - lo.ln()) / (hi.ln() - lo.ln())
        } else {
            (v - lo) / (hi - lo)
        }
    };
    let (mut left, mut right) = (0, 0);
    for &(px, py) in panel.series.iter().flat_map(|s| s.points.iter()) {
        let (u, v) = (unit(px, x, panel.log_x), unit(py, y, panel.log_y));
        if !(u.is_finite() && v.is_finite()) || v < 0.6 {
            continue;
        }
        if u < 0.45 {
            left += 1;
        }
        if u > 0.55 {
            right += 1;
        }
    }
    if right < left {
        SeriesLabelPosition::UpperRight
    } else {
        SeriesLabelPosition::UpperLeft
    }
}

/// 1, 2 and 5 times the powers of ten in [lo, hi] (lo > 0), the ends too when fewer than
/// two fall inside.
#[cfg(feature = "plots")]
fn log_key_points(lo: f64, hi: f64) -> Vec<f64> {
    let mut out = Vec::new();
    if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
        return out;
    }
    let mut decade = 10f64.powi(lo.log10().floor() as i32);
    while decade <= hi {
        for m in [1.0, 2.0, 5.0] {
            let v = m * decade;
            if v >= lo && v <= hi {
                out.push(v);
            }
        }
        decade *= 10.0;
    }
    if out.len() < 2 {
        out = vec![lo, hi];
    }
    out
}

#[cfg(all(test, feature = "plots"))]
mod tests {
    /// Key points of a log axis: 1-2-5 steps inside the range; the range's ends when a
    /// range holds fewer than two.
    #[test]
    fn log_key_points_label_a_range_within_one_decade() {
        assert_eq!(super::log_key_points(0.0188, 0.08), [0.02, 0.05]);
        assert_eq!(super::log_key_points(15.0, 140.0), [20.0, 50.0, 100.0]);
        assert_eq!(super::log_key_points(0.3, 0.45), [0.3, 0.45]);
        assert!(super::log_key_points(0.0, 1.0).is_empty());
    }
}
