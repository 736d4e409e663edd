//! Small shared plotting layer on top of `plotters`: figures made of a grid of panels (line and
//! loop charts, heat maps), colour palettes, and atomic PNG writing.
//!
//! Text is rendered with the pure-Rust `ab_glyph` rasteriser and the bundled DejaVu Sans
//! (`nemm-train/assets/fonts/`, free licence in `LICENSE-DejaVu.txt`), so no system fonts or C
//! libraries are needed.
//!
//! Used inside the crate as (the module is crate-private, so this is not a doctest):
//!
//! ```ignore
//! use crate::report::plot::{palette, Figure, LinePanel, Series};
//! let series = Series::line("loss", vec![(0.0, 1.0), (1.0, 0.5), (2.0, 0.3)], palette::categorical(0));
//! let panel = LinePanel::new("training", "epoch", "loss").with_series(series);
//! Figure::new(1, 1).with_title("run 7").with_panel(panel).save_png("loss.png".as_ref())?;
//! # Ok::<(), anyhow::Error>(())
//! ```

use anyhow::{anyhow, Context, Result};
use heatmap::draw_heatmap;
use lines::{draw_lines, draw_note};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;
use std::path::Path;
use std::sync::OnceLock;

mod heatmap;
mod lines;

pub(crate) use heatmap::{nice_levels, ColorMap, HeatmapPanel};
pub(crate) use lines::{LegendPosition, LinePanel, Series};

/// The bundled font (DejaVu Sans, Bitstream Vera / DejaVu licence).
/// Height of a footer line in pixels.
const FOOTER_LINE: u32 = 21;
static FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");
const FAMILY: &str = "sans-serif";

/// Registers the bundled font for all plotters text (idempotent).
pub(crate) fn ensure_font() -> Result<()> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        [
            FontStyle::Normal,
            FontStyle::Bold,
            FontStyle::Italic,
            FontStyle::Oblique,
        ]
        .into_iter()
        .all(|style| plotters::style::register_font(FAMILY, style, FONT).is_ok())
    });
    if ok {
        Ok(())
    } else {
        Err(anyhow!(
            "the bundled font DejaVuSans.ttf could not be parsed"
        ))
    }
}

/// Colour palettes.
pub(super) mod palette {
    use plotters::style::RGBColor;

    /// Ten well-separated categorical colours (Tableau 10), cycling.
    pub(crate) fn categorical(i: usize) -> RGBColor {
        const C: [(u8, u8, u8); 10] = [
            (31, 119, 180),
            (255, 127, 14),
            (44, 160, 44),
            (214, 39, 40),
            (148, 103, 189),
            (140, 86, 75),
            (227, 119, 194),
            (127, 127, 127),
            (188, 189, 34),
            (23, 190, 207),
        ];
        let (r, g, b) = C[i % C.len()];
        RGBColor(r, g, b)
    }

    fn interpolate(stops: &[(u8, u8, u8)], t: f64) -> RGBColor {
        let t = if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let x = t * (stops.len() - 1) as f64;
        let i = (x.floor() as usize).min(stops.len() - 2);
        let f = x - i as f64;
        let mix = |a: u8, b: u8| (f64::from(a) + f * (f64::from(b) - f64::from(a))).round() as u8;
        let (a, b) = (stops[i], stops[i + 1]);
        RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
    }

    /// Sequential colour map (viridis, 9 stops, linear in between) for `t` in \[0, 1\].
    pub(crate) fn sequential(t: f64) -> RGBColor {
        const V: [(u8, u8, u8); 9] = [
            (68, 1, 84),
            (71, 44, 122),
            (59, 81, 139),
            (44, 113, 142),
            (33, 144, 141),
            (39, 173, 129),
            (92, 200, 99),
            (170, 220, 50),
            (253, 231, 37),
        ];
        interpolate(&V, t)
    }

    /// Diverging colour map (blue - white - red) for `t` in \[0, 1\], white at 0.5.
    pub(crate) fn diverging(t: f64) -> RGBColor {
        const D: [(u8, u8, u8); 5] = [
            (33, 102, 172),
            (146, 197, 222),
            (247, 247, 247),
            (244, 165, 130),
            (178, 24, 43),
        ];
        interpolate(&D, t)
    }

    /// Sequential blue colour map (ColorBrewer YlGnBu without its yellow end: navy to light
    /// teal) for `t` in \[0, 1\]. Contains no yellow, so yellow marks stand out on it.
    pub(crate) fn ocean(t: f64) -> RGBColor {
        const O: [(u8, u8, u8); 6] = [
            (8, 29, 88),
            (37, 52, 148),
            (34, 94, 168),
            (29, 145, 192),
            (65, 182, 196),
            (161, 218, 205),
        ];
        interpolate(&O, t)
    }

    /// `c` mixed with white: `f = 0` keeps it, `f = 1` is white.
    pub(crate) fn lighten(c: RGBColor, f: f64) -> RGBColor {
        let f = if f.is_finite() {
            f.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let mix = |a: u8| (f64::from(a) + f * (255.0 - f64::from(a))).round() as u8;
        RGBColor(mix(c.0), mix(c.1), mix(c.2))
    }

    /// Colour of constraint-violation marks (the paper's yellow).
    pub(crate) const MARK: RGBColor = RGBColor(255, 221, 0);

    /// `n` colours spread over the sequential map (dark to bright, the last not too pale).
    pub(crate) fn sequence(n: usize) -> Vec<RGBColor> {
        (0..n)
            .map(|i| {
                sequential(if n > 1 {
                    0.9 * i as f64 / (n - 1) as f64
                } else {
                    0.0
                })
            })
            .collect()
    }
}

/// A panel of a figure.
#[derive(Debug, Clone)]
pub(crate) enum Panel {
    /// Line / loop / point chart.
    Lines(LinePanel),
    /// Heat map with colour bar.
    Heatmap(HeatmapPanel),
    /// A message in place of a chart (e.g. why a panel has no data).
    Note(String),
}

impl From<LinePanel> for Panel {
    fn from(p: LinePanel) -> Self {
        Panel::Lines(p)
    }
}

impl From<HeatmapPanel> for Panel {
    fn from(p: HeatmapPanel) -> Self {
        Panel::Heatmap(p)
    }
}

/// A figure: an optional title over a `rows x cols` grid of panels (row-major).
#[derive(Debug, Clone)]
pub(crate) struct Figure {
    /// Figure title.
    pub(crate) title: Option<String>,
    /// Grid rows.
    pub(crate) rows: usize,
    /// Grid columns.
    pub(crate) cols: usize,
    /// Size of one panel in pixels.
    pub(crate) panel_size: (u32, u32),
    /// Panels, row-major; missing cells stay empty.
    pub(crate) panels: Vec<Panel>,
    /// Caption under the panels (paragraphs separated by `\n`, wrapped to the figure width),
    /// e.g. what the symbols mean.
    pub(crate) footer: Option<String>,
}

impl Figure {
    /// An empty `rows x cols` figure with 560 x 420 pixel panels.
    pub(crate) fn new(rows: usize, cols: usize) -> Self {
        Figure {
            title: None,
            rows: rows.max(1),
            cols: cols.max(1),
            panel_size: (560, 420),
            panels: Vec::new(),
            footer: None,
        }
    }

    /// Sets the caption under the panels (lines separated by `\n`).
    pub(crate) fn with_footer(mut self, t: impl Into<String>) -> Self {
        self.footer = Some(t.into());
        self
    }

    fn footer_height(&self) -> u32 {
        match self.footer_lines() {
            lines if lines.is_empty() => 0,
            lines => 14 + FOOTER_LINE * lines.len() as u32,
        }
    }

    /// The footer wrapped at word boundaries to the figure width (a conservative estimate of
    /// 8 px per character of the 15 px font).
    fn footer_lines(&self) -> Vec<String> {
        let Some(text) = &self.footer else {
            return Vec::new();
        };
        let max_chars =
            ((self.panel_size.0 * self.cols as u32).saturating_sub(32) / 8).max(20) as usize;
        let mut out = Vec::new();
        for para in text.lines() {
            let mut line = String::new();
            for word in para.split_whitespace() {
                if !line.is_empty() && line.chars().count() + 1 + word.chars().count() > max_chars {
                    out.push(std::mem::take(&mut line));
                }
                if !line.is_empty() {
                    line.push(' ');
                }
                line.push_str(word);
            }
            out.push(line);
        }
        out
    }

    /// Sets the title.
    pub(crate) fn with_title(mut self, t: impl Into<String>) -> Self {
        self.title = Some(t.into());
        self
    }

    /// Appends a panel.
    pub(crate) fn with_panel(mut self, p: impl Into<Panel>) -> Self {
        self.panels.push(p.into());
        self
    }

    /// Sets the panel size in pixels.
    pub(crate) fn with_panel_size(mut self, w: u32, h: u32) -> Self {
        self.panel_size = (w, h);
        self
    }

    /// Size of the whole image in pixels.
    pub(crate) fn size(&self) -> (u32, u32) {
        let title_h = if self.title.is_some() { 40 } else { 0 };
        (
            self.panel_size.0 * self.cols as u32,
            self.panel_size.1 * self.rows as u32 + title_h + self.footer_height(),
        )
    }

    /// Renders into an RGB buffer of [`Figure::size`] (3 bytes per pixel).
    pub(crate) fn render_rgb(&self) -> Result<Vec<u8>> {
        ensure_font()?;
        let (w, h) = self.size();
        let mut buf = vec![255u8; (w * h * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            self.draw(&root)?;
            root.present()
                .map_err(|e| anyhow!("plot rendering failed: {e}"))?;
        }
        Ok(buf)
    }

    /// Writes the figure as PNG, atomically (temporary file in the same folder, then rename).
    pub(crate) fn save_png(&self, path: &Path) -> Result<()> {
        ensure_font()?;
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        // The encoder picks the format from the extension, so the temporary file ends in .png.
        let tmp = dir.join(format!(".{name}.{}.tmp.png", std::process::id()));
        let result = (|| {
            let (w, h) = self.size();
            let root = BitMapBackend::new(&tmp, (w, h)).into_drawing_area();
            self.draw(&root)?;
            root.present()
                .map_err(|e| anyhow!("cannot write {}: {e}", tmp.display()))?;
            std::fs::rename(&tmp, path)
                .with_context(|| format!("cannot move {} to {}", tmp.display(), path.display()))
        })();
        if result.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        result
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("plot rendering failed: {e:?}");
        root.fill(&WHITE).map_err(err)?;
        let body = match &self.title {
            Some(t) => {
                let (top, rest) = root.split_vertically(40);
                top.titled(t, (FAMILY, 24).into_font()).map_err(err)?;
                rest
            }
            None => root.clone(),
        };
        let footer = self.footer_lines();
        let body = if footer.is_empty() {
            body
        } else {
            let h = body.dim_in_pixel().1;
            let (rest, bottom) = body.split_vertically(h.saturating_sub(self.footer_height()));
            let style = TextStyle::from((FAMILY, 15).into_font()).color(&RGBColor(60, 60, 60));
            for (i, line) in footer.iter().enumerate() {
                bottom
                    .draw(&Text::new(
                        line.to_string(),
                        (16, 4 + FOOTER_LINE as i32 * i as i32),
                        style.clone(),
                    ))
                    .map_err(err)?;
            }
            rest
        };
        let cells = body.split_evenly((self.rows, self.cols));
        for (panel, area) in self.panels.iter().zip(cells.iter()) {
            match panel {
                Panel::Lines(p) => draw_lines(p, area)?,
                Panel::Heatmap(p) => draw_heatmap(p, area)?,
                Panel::Note(text) => draw_note(text, area)?,
            }
        }
        Ok(())
    }
}

fn padded(lo: f64, hi: f64, frac: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    if hi - lo <= f64::EPSILON * (lo.abs() + hi.abs()).max(1e-300) {
        let d = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
        return (lo - d, hi + d);
    }
    let d = frac * (hi - lo);
    (lo - d, hi + d)
}

fn data_bounds(it: impl Iterator<Item = f64>) -> (f64, f64) {
    it.filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        })
}

/// Writes an RGB buffer (3 bytes per pixel, row-major, `size.0 x size.1`, as from
/// [`Figure::render_rgb`]) as PNG, atomically (temporary file in the same folder, then
/// rename). Every error is an I/O or encoding error.
pub(crate) fn save_rgb_png(path: &Path, size: (u32, u32), rgb: &[u8]) -> Result<()> {
    let (w, h) = size;
    if rgb.len() != (w as usize) * (h as usize) * 3 {
        return Err(anyhow!(
            "RGB buffer of {} bytes does not match {w} x {h} pixels",
            rgb.len()
        ));
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.{}.tmp.png", std::process::id()));
    let result = (|| {
        {
            let mut backend = BitMapBackend::new(&tmp, (w, h));
            backend
                .blit_bitmap((0, 0), (w, h), rgb)
                .map_err(|e| anyhow!("cannot encode {}: {e:?}", tmp.display()))?;
            backend
                .present()
                .map_err(|e| anyhow!("cannot write {}: {e}", tmp.display()))?;
        }
        std::fs::rename(&tmp, path)
            .with_context(|| format!("cannot move {} to {}", tmp.display(), path.display()))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Label of a tick at `v = log10(y)` on a log axis: `y` to 2 significant digits, so that the
/// fractional-decade ticks of a short range stay distinct (`0.025`, `0.04`, ...); powers of ten
/// that [`format_tick`] would write in scientific notation (below 1e-3, from 1e5 on) print as
/// `1e-4`, like their neighbours `1e-5`.
pub(crate) fn format_log_tick(v: f64) -> String {
    if !v.is_finite() {
        return "0".into();
    }
    let y = 10f64.powf(v);
    if (v - v.round()).abs() < 1e-9 && !(-3.0..=4.0).contains(&v.round()) {
        return format!("1e{}", v.round() as i64);
    }
    let mag = y.log10().floor();
    let q = 10f64.powf(mag - 1.0);
    format_tick((y / q).round() * q)
}

/// Compact tick label: up to 4 significant digits, no trailing zeros; |v| < 1e-12 (rounding
/// residue of a tick at zero) prints as `0`.
pub(crate) fn format_tick(v: f64) -> String {
    format_tick_on(v, f64::INFINITY)
}

/// [`format_tick`] for a tick on an axis spanning `span`: with as many more decimals as the
/// axis needs to tell its ticks apart (a k_pr axis from 398.6 to 398.9 kN/m has ticks
/// 0.05 apart, which four significant digits would print as 398.9, 398.9, 398.8, ...).
pub(crate) fn format_tick_on(v: f64, span: f64) -> String {
    if v.abs() < 1e-12 || !v.is_finite() {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.1e}");
    }
    let significant = 3 - a.log10().floor() as i32;
    // plotters puts at most 10 labels on an axis, at steps of 1, 2 or 5 times a power of ten
    // (`compute_f64_key_points`), so a step is at least span / 10; one decimal more than
    // that needs is a margin (trailing zeros are trimmed below).
    let by_span = if span.is_finite() && span > 0.0 {
        1 - (span / 10.0).log10().floor() as i32
    } else {
        0
    };
    let decimals = significant.max(by_span).clamp(0, 9) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use heatmap::contour_segments;

    #[test]
    fn tick_labels_are_compact() {
        assert_eq!(format_tick(0.5), "0.5");
        assert_eq!(format_tick(-1200.0), "-1200");
        assert_eq!(format_tick(0.0125), "0.0125");
        assert_eq!(format_tick(2.0e-5), "2.0e-5");
    }

    #[test]
    fn ticks_of_a_narrow_axis_are_told_apart() {
        // plotters' ticks on 398.6 ..= 398.9 are 0.05 apart; 0.025 is a finer check.
        let labels: Vec<String> = (0..13)
            .map(|i| format_tick_on(398.6 + 0.025 * f64::from(i), 0.3))
            .collect();
        for w in labels.windows(2) {
            assert_ne!(w[0], w[1], "{labels:?}");
        }
        assert_eq!(format_tick_on(398.625, 0.3), "398.625");
        // A wide axis keeps the compact labels.
        assert_eq!(format_tick_on(0.5, 2.0), "0.5");
        assert_eq!(format_tick_on(-1200.0, 5000.0), "-1200");
    }

    #[test]
    fn figure_renders_text_and_lines_and_writes_png_atomically() {
        let pts: Vec<(f64, f64)> = (0..100)
            .map(|i| {
                let t = i as f64 * 0.0628;
                (t.cos(), t.sin())
            })
            .collect();
        let fig = Figure::new(1, 2)
            .with_title("test")
            .with_panel(
                LinePanel::new("loop", "x", "y")
                    .with_series(Series::closed("c", pts, palette::categorical(0)))
                    .with_zero_lines(),
            )
            .with_panel(
                HeatmapPanel::new(
                    "map",
                    "a",
                    "b",
                    vec![0.0, 1.0, 2.0],
                    vec![0.0, 1.0],
                    vec![vec![0.0, 1.0, 2.0], vec![3.0, 4.0, 5.0]],
                )
                .with_z_label("z"),
            );
        let rgb = fig.render_rgb().unwrap();
        let (w, h) = fig.size();
        assert_eq!(rgb.len(), (w * h * 3) as usize);
        // Something other than white was drawn (text, axes, the loop in tab:blue).
        assert!(rgb.chunks(3).any(|p| p == [31, 119, 180]));
        let dir = std::env::temp_dir().join(format!("nemm-plot-test-{}", std::process::id()));
        let path = dir.join("fig.png");
        fig.save_png(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        let leftovers: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
            .collect();
        assert!(leftovers.is_empty());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn log_tick_labels_are_distinct_values() {
        assert_eq!(format_log_tick(-2.0), "0.01");
        assert_eq!(format_log_tick(0.0), "1");
        assert_eq!(format_log_tick(-6.0), "1e-6");
        assert_eq!(format_log_tick(-4.0), "1e-4");
        assert_eq!(format_log_tick(-3.0), "0.001");
        assert_eq!(format_log_tick((0.025f64).log10()), "0.025");
        let labels: Vec<String> = (0..10)
            .map(|i| format_log_tick(-2.0 + 0.1 * f64::from(i)))
            .collect();
        let mut dedup = labels.clone();
        dedup.dedup();
        assert_eq!(labels, dedup);
    }

    #[test]
    fn footers_wrap_to_the_figure_width() {
        let long = "word ".repeat(200);
        let fig = Figure::new(1, 1).with_panel_size(400, 300);
        assert_eq!(fig.size(), (400, 300));
        let one = fig.clone().with_footer("short");
        assert_eq!(one.size(), (400, 300 + 14 + 21));
        let wrapped = fig.clone().with_footer(format!("{long}\nsecond paragraph"));
        let lines = wrapped.footer_lines();
        assert!(
            lines.len() > 3 && lines.iter().all(|l| l.len() <= 46),
            "{lines:?}"
        );
        assert_eq!(lines.last().map(String::as_str), Some("second paragraph"));
        assert_eq!(wrapped.size().1, 300 + 14 + 21 * lines.len() as u32);
        assert_eq!(wrapped.render_rgb().unwrap().len(), {
            let (w, h) = wrapped.size();
            (w * h * 3) as usize
        });
    }

    #[test]
    fn nice_levels_are_round_and_inside() {
        let l = nice_levels(0.0, 1.0, 5);
        assert_eq!(l.len(), 4);
        assert!(l
            .iter()
            .zip([0.2, 0.4, 0.6, 0.8])
            .all(|(a, b)| (a - b).abs() < 1e-12));
        let l = nice_levels(1234.0, 2871.0, 8);
        assert!(l.len() >= 5 && l.len() <= 10, "{l:?}");
        assert!(l
            .iter()
            .all(|v| *v > 1234.0 && *v < 2871.0 && (v / 250.0).fract() == 0.0));
        assert!(nice_levels(1.0, 1.0, 5).is_empty());
        assert!(nice_levels(f64::NAN, 1.0, 5).is_empty());
    }

    #[test]
    fn contour_of_a_plane_is_a_straight_line() {
        // z = x + y on [0, 4]^2: the level 4 is the anti-diagonal x + y = 4.
        let g: Vec<f64> = (0..5).map(f64::from).collect();
        let z: Vec<Vec<f64>> = g
            .iter()
            .map(|y| g.iter().map(|x| x + y).collect())
            .collect();
        let segs = contour_segments(&g, &g, &z, 3.5);
        assert!(!segs.is_empty());
        for (a, b) in &segs {
            assert!((a.0 + a.1 - 3.5).abs() < 1e-12 && (b.0 + b.1 - 3.5).abs() < 1e-12);
        }
        // Total length of the iso-line x + y = 3.5 inside the square: 3.5 * sqrt(2).
        let len: f64 = segs
            .iter()
            .map(|(a, b)| ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt())
            .sum();
        assert!((len - 3.5 * 2f64.sqrt()).abs() < 1e-9, "{len}");
        assert!(contour_segments(&g, &g, &z, 100.0).is_empty());
    }

    #[test]
    fn marks_overlays_dashes_and_notes_render_and_rgb_buffers_save() {
        let g: Vec<f64> = (0..20).map(|i| f64::from(i) / 19.0).collect();
        let z: Vec<Vec<f64>> = g
            .iter()
            .map(|y| g.iter().map(|x| x * y).collect())
            .collect();
        let mark: Vec<Vec<bool>> = g
            .iter()
            .map(|y| g.iter().map(|x| *x > 0.8 && *y > 0.8).collect())
            .collect();
        let fig = Figure::new(1, 3)
            .with_panel(
                HeatmapPanel::new("m", "x", "y", g.clone(), g.clone(), z)
                    .with_colormap(ColorMap::Ocean)
                    .with_contours(nice_levels(0.0, 1.0, 4))
                    .with_marks(mark, Some("violation".into()))
                    .with_overlay(Series::dashed(
                        "box",
                        vec![(0.1, 0.1), (0.5, 0.5)],
                        palette::categorical(3),
                    )),
            )
            .with_panel(
                LinePanel::new("l", "x", "y")
                    .with_series(
                        Series::dashed("d", vec![(0.0, 0.0), (1.0, 1.0)], palette::categorical(1))
                            .with_width(3),
                    )
                    .with_series(Series::dots("p", vec![(0.5, 0.2)], palette::categorical(2))),
            )
            .with_panel(Panel::Note("nothing\nto show".into()));
        let rgb = fig.render_rgb().unwrap();
        assert!(
            rgb.chunks(3).any(|p| p == [255, 221, 0]),
            "yellow marks drawn"
        );
        assert!(rgb.chunks(3).any(|p| p == [8, 29, 88]), "ocean map drawn");
        let dir = std::env::temp_dir().join(format!("nemm-plot-rgb-{}", std::process::id()));
        let path = dir.join("rgb.png");
        save_rgb_png(&path, fig.size(), &rgb).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        let w = u32::from_be_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]);
        let h = u32::from_be_bytes([bytes[20], bytes[21], bytes[22], bytes[23]]);
        assert_eq!((w, h), fig.size());
        assert!(save_rgb_png(&path, (3, 3), &rgb).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
