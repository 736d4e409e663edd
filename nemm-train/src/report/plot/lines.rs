//! Line panels: series, their styles and legend, and how they are drawn.

use super::{data_bounds, format_log_tick, format_tick_on, padded, palette, FAMILY};
use anyhow::{anyhow, Result};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum SeriesStyle {
    /// Polyline through the points.
    Line,
    /// Polyline closed back to its first point (hysteresis loops).
    Loop,
    /// Dots.
    Points,
    /// Dashed polyline (references, model estimates over measurements).
    Dashed,
    /// Filled polygon through the points in a light shade of the colour (a band: the
    /// upper edge left to right, then the lower edge right to left).
    Area,
}

/// One data series of a line panel.
#[derive(Debug, Clone)]
pub(crate) struct Series {
    /// Legend label (no legend entry if `None`).
    pub(crate) label: Option<String>,
    /// Data points (x, y); non-finite points break the line.
    pub(crate) points: Vec<(f64, f64)>,
    /// Colour.
    pub(crate) color: RGBColor,
    /// Line width / dot radius in pixels.
    pub(crate) width: u32,
    /// Drawing style.
    pub(crate) style: SeriesStyle,
}

impl Series {
    /// A labelled polyline of width 2.
    pub(crate) fn line(label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Series {
            label: Some(label.into()),
            points,
            color,
            width: 2,
            style: SeriesStyle::Line,
        }
    }

    /// A labelled closed loop of width 2.
    pub(crate) fn closed(
        label: impl Into<String>,
        points: Vec<(f64, f64)>,
        color: RGBColor,
    ) -> Self {
        Series {
            label: Some(label.into()),
            points,
            color,
            width: 2,
            style: SeriesStyle::Loop,
        }
    }

    /// Labelled dots of radius 2.
    pub(crate) fn dots(label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Series {
            label: Some(label.into()),
            points,
            color,
            width: 2,
            style: SeriesStyle::Points,
        }
    }

    /// A labelled dashed polyline of width 2.
    pub(crate) fn dashed(
        label: impl Into<String>,
        points: Vec<(f64, f64)>,
        color: RGBColor,
    ) -> Self {
        Series {
            label: Some(label.into()),
            points,
            color,
            width: 2,
            style: SeriesStyle::Dashed,
        }
    }

    /// A labelled band between `lower` and `upper` (one `(x, lower, upper)` per point, `x`
    /// ascending), filled in a light shade of `color`.
    pub(crate) fn band(
        label: impl Into<String>,
        points: &[(f64, f64, f64)],
        color: RGBColor,
    ) -> Self {
        let outline = points
            .iter()
            .map(|&(x, _, hi)| (x, hi))
            .chain(points.iter().rev().map(|&(x, lo, _)| (x, lo)))
            .collect();
        Series {
            label: Some(label.into()),
            points: outline,
            color,
            width: 1,
            style: SeriesStyle::Area,
        }
    }

    /// Sets the line width / dot radius in pixels.
    pub(crate) fn with_width(mut self, width: u32) -> Self {
        self.width = width;
        self
    }

    /// Removes the legend entry.
    pub(crate) fn unlabelled(mut self) -> Self {
        self.label = None;
        self
    }
}

/// Where the legend goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LegendPosition {
    /// No legend.
    None,
    /// Upper left corner.
    UpperLeft,
    /// Upper right corner.
    UpperRight,
    /// Lower left corner.
    LowerLeft,
    /// Lower right corner.
    LowerRight,
}

/// A chart of line / loop / point series in Cartesian coordinates.
#[derive(Debug, Clone)]
pub(crate) struct LinePanel {
    /// Panel caption.
    pub(crate) title: String,
    /// x-axis label.
    pub(crate) x_label: String,
    /// y-axis label.
    pub(crate) y_label: String,
    /// Series, drawn in order.
    pub(crate) series: Vec<Series>,
    /// x range (automatic with 3 % padding if `None`).
    pub(crate) x_range: Option<(f64, f64)>,
    /// y range (automatic with 5 % padding if `None`).
    pub(crate) y_range: Option<(f64, f64)>,
    /// Plot log10(y) with `10^k` tick labels (non-positive values are dropped).
    pub(crate) log_y: bool,
    /// Thin grey lines at these y values (e.g. 0).
    pub(crate) reference_y: Vec<f64>,
    /// Thin grey lines at these x values.
    pub(crate) reference_x: Vec<f64>,
    /// Legend placement.
    pub(crate) legend: LegendPosition,
}

impl LinePanel {
    /// An empty panel with a caption and axis labels.
    pub(crate) fn new(
        title: impl Into<String>,
        x_label: impl Into<String>,
        y_label: impl Into<String>,
    ) -> Self {
        LinePanel {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            series: Vec::new(),
            x_range: None,
            y_range: None,
            log_y: false,
            reference_y: Vec::new(),
            reference_x: Vec::new(),
            legend: LegendPosition::UpperLeft,
        }
    }

    /// Adds a series.
    pub(crate) fn with_series(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }

    /// Fixes the x range.
    pub(crate) fn with_x_range(mut self, lo: f64, hi: f64) -> Self {
        self.x_range = Some((lo, hi));
        self
    }

    /// Fixes the y range.
    pub(crate) fn with_y_range(mut self, lo: f64, hi: f64) -> Self {
        self.y_range = Some((lo, hi));
        self
    }

    /// Sets the legend position.
    pub(crate) fn with_legend(mut self, pos: LegendPosition) -> Self {
        self.legend = pos;
        self
    }

    /// Adds grey reference lines at x = 0 and y = 0.
    pub(crate) fn with_zero_lines(mut self) -> Self {
        self.reference_x.push(0.0);
        self.reference_y.push(0.0);
        self
    }

    fn transformed(&self, y: f64) -> Option<f64> {
        if self.log_y {
            (y > 0.0).then(|| y.log10())
        } else {
            Some(y)
        }
    }
}

pub(super) fn draw_lines<DB: DrawingBackend>(
    p: &LinePanel,
    area: &DrawingArea<DB, Shift>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("plot rendering failed: {e:?}");
    let pts = |s: &Series| -> Vec<(f64, f64)> {
        s.points
            .iter()
            .map(|&(x, y)| (x, p.transformed(y).unwrap_or(f64::NAN)))
            .collect()
    };
    let all: Vec<Vec<(f64, f64)>> = p.series.iter().map(pts).collect();
    let (x0, x1) = p.x_range.unwrap_or_else(|| {
        let (a, b) = data_bounds(all.iter().flatten().map(|q| q.0));
        padded(a, b, 0.03)
    });
    let (y0, y1) = match p.y_range {
        Some((a, b)) => (p.transformed(a).unwrap_or(a), p.transformed(b).unwrap_or(b)),
        None => {
            let (a, b) = data_bounds(all.iter().flatten().map(|q| q.1));
            padded(a, b, 0.05)
        }
    };
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, (FAMILY, 17).into_font())
        .margin(8)
        .x_label_area_size(38)
        .y_label_area_size(58)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    let log_y = p.log_y;
    let y_fmt = move |v: &f64| {
        if log_y {
            format_log_tick(*v)
        } else {
            format_tick_on(*v, y1 - y0)
        }
    };
    let x_fmt = |v: &f64| format_tick_on(*v, x1 - x0);
    chart
        .configure_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style((FAMILY, 13).into_font())
        .axis_desc_style((FAMILY, 14).into_font())
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(215, 215, 215))
        .draw()
        .map_err(err)?;
    let grey = RGBColor(120, 120, 120);
    for &y in &p.reference_y {
        if let Some(y) = p.transformed(y) {
            chart
                .draw_series(LineSeries::new([(x0, y), (x1, y)], grey.stroke_width(1)))
                .map_err(err)?;
        }
    }
    for &x in &p.reference_x {
        chart
            .draw_series(LineSeries::new([(x, y0), (x, y1)], grey.stroke_width(1)))
            .map_err(err)?;
    }
    let mut any_label = false;
    for (s, pts) in p.series.iter().zip(all) {
        any_label |= draw_series(&mut chart, s, pts)?;
    }
    if any_label {
        draw_legend(&mut chart, p.legend)?;
    }
    Ok(())
}

/// A chart in `f64` x `f64` coordinates.
pub(super) type Chart2d<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

pub(super) fn draw_legend<'a, DB: DrawingBackend + 'a>(
    chart: &mut Chart2d<'a, DB>,
    legend: LegendPosition,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let pos = match legend {
        LegendPosition::None => return Ok(()),
        LegendPosition::UpperLeft => SeriesLabelPosition::UpperLeft,
        LegendPosition::UpperRight => SeriesLabelPosition::UpperRight,
        LegendPosition::LowerLeft => SeriesLabelPosition::LowerLeft,
        LegendPosition::LowerRight => SeriesLabelPosition::LowerRight,
    };
    chart
        .configure_series_labels()
        .position(pos)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(190, 190, 190))
        .label_font((FAMILY, 13).into_font())
        .draw()
        .map_err(|e| anyhow!("plot rendering failed: {e:?}"))
}

/// Draws one series (points already transformed to chart coordinates); returns whether it
/// added a legend entry.
pub(super) fn draw_series<'a, DB: DrawingBackend + 'a>(
    chart: &mut Chart2d<'a, DB>,
    s: &Series,
    pts: Vec<(f64, f64)>,
) -> Result<bool>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("plot rendering failed: {e:?}");
    let style = s.color.stroke_width(s.width);
    let shade = palette::lighten(s.color, 0.7);
    let anno = match s.style {
        SeriesStyle::Area => chart
            .draw_series(std::iter::once(Polygon::new(
                pts.into_iter()
                    .filter(|q| q.0.is_finite() && q.1.is_finite())
                    .collect::<Vec<_>>(),
                shade.filled(),
            )))
            .map_err(err)?,
        SeriesStyle::Points => chart
            .draw_series(
                pts.iter()
                    .filter(|q| q.0.is_finite() && q.1.is_finite())
                    .map(|&q| Circle::new(q, s.width, s.color.filled())),
            )
            .map_err(err)?,
        SeriesStyle::Line | SeriesStyle::Loop | SeriesStyle::Dashed => {
            let mut segs: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
            for q in &pts {
                if q.0.is_finite() && q.1.is_finite() {
                    if let Some(v) = segs.last_mut() {
                        v.push(*q);
                    }
                } else if segs.last().is_some_and(|v| !v.is_empty()) {
                    segs.push(Vec::new());
                }
            }
            if s.style == SeriesStyle::Loop && segs.len() == 1 {
                if let Some(first) = segs[0].first().copied() {
                    segs[0].push(first);
                }
            }
            let mut last = None;
            for seg in segs.into_iter().filter(|v| !v.is_empty()) {
                last = Some(if s.style == SeriesStyle::Dashed {
                    let dash = 4 * s.width.max(2) as i32;
                    chart
                        .draw_series(DashedLineSeries::new(seg, dash, dash * 2 / 3, style))
                        .map_err(err)?
                } else if s.width > 1 {
                    // Thick polylines are polygonised as a whole by the backend, and a
                    // self-overlapping one (a loop traced twice) renders hollow; separate
                    // segments do not.
                    chart
                        .draw_series(
                            seg.windows(2)
                                .map(|w| PathElement::new(vec![w[0], w[1]], style)),
                        )
                        .map_err(err)?
                } else {
                    chart
                        .draw_series(LineSeries::new(seg, style))
                        .map_err(err)?
                });
            }
            match last {
                Some(a) => a,
                None => return Ok(false),
            }
        }
    };
    let Some(label) = &s.label else {
        return Ok(false);
    };
    let (c, w, st) = (s.color, s.width, s.style);
    anno.label(label.as_str()).legend(move |(x, y)| {
        let e = EmptyElement::at((x, y));
        match st {
            SeriesStyle::Area => {
                e + Circle::new((0, 0), 0, c.filled())
                    + PathElement::new([(0, 0), (18, 0)], shade.stroke_width(10))
                    + PathElement::new([(0, 0), (0, 0)], c.stroke_width(1))
            }
            SeriesStyle::Points => {
                e + Circle::new((9, 0), w.max(3), c.filled())
                    + PathElement::new([(0, 0), (0, 0)], c.stroke_width(1))
                    + PathElement::new([(0, 0), (0, 0)], c.stroke_width(1))
            }
            SeriesStyle::Dashed => {
                e + Circle::new((0, 0), 0, c.filled())
                    + PathElement::new([(0, 0), (7, 0)], c.stroke_width(3))
                    + PathElement::new([(11, 0), (18, 0)], c.stroke_width(3))
            }
            _ => {
                e + Circle::new((0, 0), 0, c.filled())
                    + PathElement::new([(0, 0), (18, 0)], c.stroke_width(3))
                    + PathElement::new([(0, 0), (0, 0)], c.stroke_width(1))
            }
        }
    });
    Ok(true)
}

pub(super) fn draw_note<DB: DrawingBackend>(text: &str, area: &DrawingArea<DB, Shift>) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("plot rendering failed: {e:?}");
    let (w, h) = area.dim_in_pixel();
    let (w, h) = (w as i32, h as i32);
    area.draw(&Rectangle::new(
        [(12, 12), (w - 12, h - 12)],
        RGBColor(200, 200, 200).stroke_width(1),
    ))
    .map_err(err)?;
    let lines: Vec<&str> = text.lines().collect();
    let style = TextStyle::from((FAMILY, 16).into_font())
        .color(&RGBColor(90, 90, 90))
        .pos(Pos::new(HPos::Center, VPos::Center));
    let n = lines.len() as i32;
    for (i, line) in lines.iter().enumerate() {
        let y = h / 2 + (2 * i as i32 - (n - 1)) * 11;
        area.draw(&Text::new(line.to_string(), (w / 2, y), style.clone()))
            .map_err(err)?;
    }
    Ok(())
}
