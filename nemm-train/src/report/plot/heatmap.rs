//! Heatmap panels: colour maps, contour levels and lines, and how they are drawn.

use super::lines::{draw_legend, draw_series, Chart2d, LegendPosition, Series};
use super::{data_bounds, format_tick_on, padded, palette, FAMILY};
use anyhow::{anyhow, Result};
use plotters::coord::Shift;
use plotters::prelude::*;

/// A heat map of `z(x, y)` on a regular grid (e.g. a learned function over two inputs).
#[derive(Debug, Clone)]
pub(crate) struct HeatmapPanel {
    /// Panel caption.
    pub(crate) title: String,
    /// x-axis label.
    pub(crate) x_label: String,
    /// y-axis label.
    pub(crate) y_label: String,
    /// Cell centres in x (increasing).
    pub(crate) x: Vec<f64>,
    /// Cell centres in y (increasing).
    pub(crate) y: Vec<f64>,
    /// Values `z[iy][ix]`.
    pub(crate) z: Vec<Vec<f64>>,
    /// Colour range (automatic min..max if `None`).
    pub(crate) z_range: Option<(f64, f64)>,
    /// Label of the colour bar.
    pub(crate) z_label: String,
    /// Use the diverging map (centred range) instead of the sequential one.
    pub(crate) diverging: bool,
    /// Cells drawn with a hatch colour (e.g. constraint violations), `mark[iy][ix]`.
    pub(crate) mark: Option<Vec<Vec<bool>>>,
    /// Colour map; overrides [`HeatmapPanel::diverging`] when set.
    pub(crate) colormap: Option<ColorMap>,
    /// Colour of marked cells (default [`palette::MARK`], yellow).
    pub(crate) mark_color: Option<RGBColor>,
    /// Legend entry of the marked cells (none if `None`).
    pub(crate) mark_label: Option<String>,
    /// Iso-lines at these z values (thin dark lines, also ticked on the colour bar).
    pub(crate) contours: Vec<f64>,
    /// Series drawn over the map (e.g. the training range, data points); labelled ones go
    /// into the legend.
    pub(crate) overlay: Vec<Series>,
    /// Legend placement (used when an overlay series or the marks have a label).
    pub(crate) legend: LegendPosition,
}

/// Colour maps of a heat map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ColorMap {
    /// [`palette::sequential`] (viridis; its bright end is yellow).
    Viridis,
    /// [`palette::diverging`] (blue - white - red).
    Diverging,
    /// [`palette::ocean`] (navy to light teal, no yellow: use with yellow marks).
    Ocean,
}

impl ColorMap {
    /// Colour at `t` in \[0, 1\].
    pub(crate) fn color(self, t: f64) -> RGBColor {
        match self {
            ColorMap::Viridis => palette::sequential(t),
            ColorMap::Diverging => palette::diverging(t),
            ColorMap::Ocean => palette::ocean(t),
        }
    }
}

impl HeatmapPanel {
    /// A heat map of `z[iy][ix]` over cell centres `x`, `y` with the sequential colour map,
    /// automatic range, no marks, contours or overlays.
    pub(crate) fn new(
        title: impl Into<String>,
        x_label: impl Into<String>,
        y_label: impl Into<String>,
        x: Vec<f64>,
        y: Vec<f64>,
        z: Vec<Vec<f64>>,
    ) -> Self {
        HeatmapPanel {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            x,
            y,
            z,
            z_range: None,
            z_label: String::new(),
            diverging: false,
            mark: None,
            colormap: None,
            mark_color: None,
            mark_label: None,
            contours: Vec::new(),
            overlay: Vec::new(),
            legend: LegendPosition::UpperRight,
        }
    }

    /// Sets the colour-bar label.
    pub(crate) fn with_z_label(mut self, label: impl Into<String>) -> Self {
        self.z_label = label.into();
        self
    }

    /// Sets the colour map.
    pub(crate) fn with_colormap(mut self, map: ColorMap) -> Self {
        self.colormap = Some(map);
        self
    }

    /// Marks cells (`mark[iy][ix]`), with an optional legend entry.
    pub(crate) fn with_marks(mut self, mark: Vec<Vec<bool>>, label: Option<String>) -> Self {
        self.mark = Some(mark);
        self.mark_label = label;
        self
    }

    /// Draws iso-lines at these levels.
    pub(crate) fn with_contours(mut self, levels: Vec<f64>) -> Self {
        self.contours = levels;
        self
    }

    /// Adds a series over the map.
    pub(crate) fn with_overlay(mut self, s: Series) -> Self {
        self.overlay.push(s);
        self
    }

    /// Sets the legend position.
    pub(crate) fn with_legend(mut self, pos: LegendPosition) -> Self {
        self.legend = pos;
        self
    }
}

/// About `n` "nice" levels (multiples of 1, 2 or 5 times a power of ten) inside `[lo, hi]`,
/// e.g. for contour lines; empty for an empty or non-finite range.
pub(crate) fn nice_levels(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo || n == 0 {
        return Vec::new();
    }
    let raw = (hi - lo) / n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last)
        .map(|k| k as f64 * step)
        .filter(|v| *v > lo && *v < hi)
        .collect()
}

pub(super) fn draw_heatmap<DB: DrawingBackend>(
    p: &HeatmapPanel,
    area: &DrawingArea<DB, Shift>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let (nx, ny) = (p.x.len(), p.y.len());
    if nx == 0 || ny == 0 || p.z.len() != ny || p.z.iter().any(|row| row.len() != nx) {
        return Err(anyhow!(
            "heat map '{}': z must be {ny} rows of {nx} values",
            p.title
        ));
    }
    let (xe, ye) = (cell_edges(&p.x), cell_edges(&p.y));
    let scale = ColorScale::of(p);
    let (main, bar) = area.split_horizontally(area.dim_in_pixel().0.saturating_sub(90));
    let mut chart = ChartBuilder::on(&main)
        .caption(&p.title, (FAMILY, 17).into_font())
        .margin(8)
        .x_label_area_size(38)
        .y_label_area_size(58)
        .build_cartesian_2d(xe[0]..xe[nx], ye[0]..ye[ny])
        .map_err(render_failed)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&|v| format_tick_on(*v, xe[nx] - xe[0]))
        .y_label_formatter(&|v| format_tick_on(*v, ye[ny] - ye[0]))
        .label_style((FAMILY, 13).into_font())
        .axis_desc_style((FAMILY, 14).into_font())
        .draw()
        .map_err(render_failed)?;
    draw_cells(&mut chart, p, (&xe, &ye), &scale)?;
    // Iso-lines (marching squares between cell centres).
    for &level in &p.contours {
        let segs = contour_segments(&p.x, &p.y, &p.z, level);
        chart
            .draw_series(
                segs.into_iter()
                    .map(|(a, b)| PathElement::new(vec![a, b], iso_line())),
            )
            .map_err(render_failed)?;
    }
    draw_overlay(&mut chart, p)?;
    draw_color_bar(&bar, p, &scale)
}

/// The error of a failed plotters call.
fn render_failed(e: impl std::fmt::Debug) -> anyhow::Error {
    anyhow!("plot rendering failed: {e:?}")
}

/// The style of the iso-lines (on the map and the colour bar).
fn iso_line() -> ShapeStyle {
    RGBColor(0, 0, 0).mix(0.55).stroke_width(1)
}

/// Cell edges around cell centres `c` (half-way between centres, the outer ones mirrored).
fn cell_edges(c: &[f64]) -> Vec<f64> {
    if c.len() == 1 {
        return vec![c[0] - 0.5, c[0] + 0.5];
    }
    let mut e = Vec::with_capacity(c.len() + 1);
    e.push(c[0] - 0.5 * (c[1] - c[0]));
    for w in c.windows(2) {
        e.push(0.5 * (w[0] + w[1]));
    }
    e.push(c[c.len() - 1] + 0.5 * (c[c.len() - 1] - c[c.len() - 2]));
    e
}

/// The colours of a heat map's values: its colour map over `[z0, z1]`.
struct ColorScale {
    map: ColorMap,
    z0: f64,
    z1: f64,
}

impl ColorScale {
    /// The panel's colour map over its range: `z_range`, else the data's (centred on zero for
    /// the diverging map), widened when it is empty.
    fn of(p: &HeatmapPanel) -> Self {
        let (mut z0, mut z1) = p
            .z_range
            .unwrap_or_else(|| data_bounds(p.z.iter().flatten().copied()));
        if p.diverging && p.z_range.is_none() {
            let m = z0.abs().max(z1.abs());
            (z0, z1) = (-m, m);
        }
        if z1.partial_cmp(&z0) != Some(std::cmp::Ordering::Greater) {
            (z0, z1) = padded(z0, z1, 0.0);
        }
        let map = p.colormap.unwrap_or(if p.diverging {
            ColorMap::Diverging
        } else {
            ColorMap::Viridis
        });
        ColorScale { map, z0, z1 }
    }

    /// The colour of `z` (grey for a non-finite value).
    fn color(&self, z: f64) -> RGBColor {
        if z.is_finite() {
            self.map.color((z - self.z0) / (self.z1 - self.z0))
        } else {
            RGBColor(190, 190, 190)
        }
    }
}

impl HeatmapPanel {
    /// The colour of the marked cells.
    fn mark_fill(&self) -> RGBColor {
        self.mark_color.unwrap_or(palette::MARK)
    }

    /// `true` if cell `(ix, iy)` is marked.
    fn is_marked(&self, ix: usize, iy: usize) -> bool {
        self.mark
            .as_ref()
            .is_some_and(|m| m.get(iy).and_then(|r| r.get(ix)).copied().unwrap_or(false))
    }
}

/// Fills the cells between the `edges` (x, y) with the colour of their value, marked cells
/// with the mark colour.
fn draw_cells<'a, DB: DrawingBackend + 'a>(
    chart: &mut Chart2d<'a, DB>,
    p: &HeatmapPanel,
    (xe, ye): (&[f64], &[f64]),
    scale: &ColorScale,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let (nx, ny) = (p.x.len(), p.y.len());
    let mark_color = p.mark_fill();
    chart
        .draw_series(
            (0..ny)
                .flat_map(|iy| (0..nx).map(move |ix| (ix, iy)))
                .map(|(ix, iy)| {
                    let c = if p.is_marked(ix, iy) {
                        mark_color
                    } else {
                        scale.color(p.z[iy][ix])
                    };
                    Rectangle::new([(xe[ix], ye[iy]), (xe[ix + 1], ye[iy + 1])], c.filled())
                }),
        )
        .map_err(render_failed)?;
    Ok(())
}

/// Draws the overlay series and the legend entry of the marks, and the legend when any of
/// them has a label.
fn draw_overlay<'a, DB: DrawingBackend + 'a>(
    chart: &mut Chart2d<'a, DB>,
    p: &HeatmapPanel,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let mut any_label = false;
    for s in &p.overlay {
        any_label |= draw_series(chart, s, s.points.clone())?;
    }
    if let (Some(label), true) = (&p.mark_label, p.mark.is_some()) {
        any_label = true;
        let mark_color = p.mark_fill();
        chart
            .draw_series(std::iter::empty::<Circle<(f64, f64), u32>>())
            .map_err(render_failed)?
            .label(label.as_str())
            .legend(move |(x, y)| {
                Rectangle::new([(x, y - 6), (x + 18, y + 6)], mark_color.filled())
            });
    }
    if any_label {
        draw_legend(chart, p.legend)?;
    }
    Ok(())
}

/// The colour bar in `bar`: the colour scale with its ticks, label and the iso-line levels.
fn draw_color_bar<DB: DrawingBackend>(
    bar: &DrawingArea<DB, Shift>,
    p: &HeatmapPanel,
    scale: &ColorScale,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let (z0, z1) = (scale.z0, scale.z1);
    let mut cb = ChartBuilder::on(bar)
        .margin_top(34)
        .margin_bottom(46)
        .margin_right(8)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..1.0, z0..z1)
        .map_err(render_failed)?;
    cb.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(p.z_label.as_str())
        .y_label_formatter(&|v| format_tick_on(*v, z1 - z0))
        .label_style((FAMILY, 12).into_font())
        .axis_desc_style((FAMILY, 13).into_font())
        .draw()
        .map_err(render_failed)?;
    let steps = 64;
    cb.draw_series((0..steps).map(|i| {
        let a = z0 + (z1 - z0) * i as f64 / steps as f64;
        let b = z0 + (z1 - z0) * (i + 1) as f64 / steps as f64;
        Rectangle::new([(0.0, a), (1.0, b)], scale.color(0.5 * (a + b)).filled())
    }))
    .map_err(render_failed)?;
    cb.draw_series(
        p.contours
            .iter()
            .filter(|l| **l > z0 && **l < z1)
            .map(|&l| PathElement::new(vec![(0.0, l), (1.0, l)], iso_line())),
    )
    .map_err(render_failed)?;
    Ok(())
}

/// Iso-line segments of `z[iy][ix]` (values at the points `(x[ix], y[iy])`) at `level`, by
/// marching squares with linear interpolation along cell edges; saddles are resolved by the
/// cell mean. Cells with a non-finite corner are skipped.
pub(crate) fn contour_segments(
    x: &[f64],
    y: &[f64],
    z: &[Vec<f64>],
    level: f64,
) -> Vec<((f64, f64), (f64, f64))> {
    let mut out = Vec::new();
    if x.len() < 2 || y.len() < 2 || z.len() != y.len() || z.iter().any(|r| r.len() != x.len()) {
        return out;
    }
    let lerp = |p: (f64, f64, f64), q: (f64, f64, f64)| {
        let t = if q.2 != p.2 {
            ((level - p.2) / (q.2 - p.2)).clamp(0.0, 1.0)
        } else {
            0.5
        };
        (p.0 + t * (q.0 - p.0), p.1 + t * (q.1 - p.1))
    };
    for iy in 0..y.len() - 1 {
        for ix in 0..x.len() - 1 {
            // Corners counter-clockwise from bottom left: a, b, c, d.
            let a = (x[ix], y[iy], z[iy][ix]);
            let b = (x[ix + 1], y[iy], z[iy][ix + 1]);
            let c = (x[ix + 1], y[iy + 1], z[iy + 1][ix + 1]);
            let d = (x[ix], y[iy + 1], z[iy + 1][ix]);
            if ![a.2, b.2, c.2, d.2].iter().all(|v| v.is_finite()) {
                continue;
            }
            let case = usize::from(a.2 >= level)
                | usize::from(b.2 >= level) << 1
                | usize::from(c.2 >= level) << 2
                | usize::from(d.2 >= level) << 3;
            let (bottom, right, top, left) =
                (|| lerp(a, b), || lerp(b, c), || lerp(d, c), || lerp(a, d));
            let centre_high = (a.2 + b.2 + c.2 + d.2) / 4.0 >= level;
            match case {
                0 | 15 => {}
                1 | 14 => out.push((left(), bottom())),
                2 | 13 => out.push((bottom(), right())),
                3 | 12 => out.push((left(), right())),
                4 | 11 => out.push((right(), top())),
                6 | 9 => out.push((bottom(), top())),
                7 | 8 => out.push((left(), top())),
                5 => {
                    if centre_high {
                        out.push((bottom(), right()));
                        out.push((left(), top()));
                    } else {
                        out.push((left(), bottom()));
                        out.push((right(), top()));
                    }
                }
                _ => {
                    // 10: b and d high.
                    if centre_high {
                        out.push((left(), bottom()));
                        out.push((right(), top()));
                    } else {
                        out.push((bottom(), right()));
                        out.push((left(), top()));
                    }
                }
            }
        }
    }
    out
}
