//! A field over the arena: a viridis colour map (linear, or logarithmic over [`LOG_DECADES`]
//! decades below the maximum), obstacles in grey, axes in metres, a title and a colour bar
//! labelled in the field's unit.

use colorous::VIRIDIS;
use ndarray::Array2;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::report::belief::{BeliefPlot, draw_run};
use crate::report::{Plot, colour, text};

/// Decades shown below the maximum on a log scale.
pub const LOG_DECADES: f64 = 4.0;

const OBSTACLE: RGBColor = RGBColor(90, 90, 90);
const MARGIN: u32 = 10;
const TITLE_H: u32 = 30;
const X_LABEL: u32 = 45;
const Y_LABEL: u32 = 60;
const BAR_W: u32 = 20;
const BAR_LABEL: u32 = 95;

/// How to draw a field.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldPlot {
    /// Title printed above the map.
    pub title: String,
    /// Logarithmic colour scale over [`LOG_DECADES`] decades below the maximum.
    pub log: bool,
    /// Unit shown beside the colour bar.
    pub unit: String,
}

/// A field panel (see the module's documentation).
#[derive(Debug, Clone)]
pub struct FieldPanel<'a> {
    field: Array2<f64>,
    layout: &'a Layout,
    plot: FieldPlot,
    /// A run drawn on top (see [`crate::report::belief`]).
    pub(crate) run: Option<Box<BeliefPlot<'a>>>,
    /// Colour scale bounds (of log10 of the values on a log scale).
    lo: f64,
    hi: f64,
}

impl<'a> FieldPanel<'a> {
    /// A `[ny, nx]` field on the layout's grid.
    ///
    /// # Errors
    /// [`Error::Parameter`] when the field's shape is not the layout's grid or it holds NaN.
    pub fn new(field: Array2<f64>, layout: &'a Layout, plot: FieldPlot) -> Result<Self> {
        if field.dim() != layout.shape() {
            return Err(Error::Parameter(format!(
                "field shape {:?} does not match the layout grid {:?}",
                field.dim(),
                layout.shape()
            )));
        }
        if field.iter().any(|v| v.is_nan()) {
            return Err(Error::Parameter("field contains NaN".into()));
        }
        let vmax = field.iter().copied().fold(0.0_f64, f64::max);
        let vmin = field.iter().copied().fold(0.0_f64, f64::min);
        let (lo, hi) = match (plot.log, vmax > 0.0) {
            (true, true) => (vmax.log10() - LOG_DECADES, vmax.log10()),
            (true, false) => (-LOG_DECADES, 0.0),
            (false, _) => (vmin, if vmax > vmin { vmax } else { vmin + 1.0 }),
        };
        Ok(Self {
            field,
            layout,
            plot,
            run: None,
            lo,
            hi,
        })
    }

    /// Pixels per cell: the map is about 960 pixels wide.
    fn cell_px(&self) -> u32 {
        (960 / self.layout.shape().1 as u32).clamp(2, 16)
    }

    pub(crate) fn size(&self) -> (u32, u32) {
        let (ny, nx) = self.layout.shape();
        let s = self.cell_px();
        let w = 4 * MARGIN + Y_LABEL + nx as u32 * s + BAR_W + BAR_LABEL;
        (w, TITLE_H + 2 * MARGIN + ny as u32 * s + X_LABEL)
    }

    pub(crate) fn draw<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        let (title, body) = area.split_vertically(TITLE_H);
        let at = ((MARGIN + Y_LABEL) as i32, 8);
        title.draw_text(&self.plot.title, &text(17), at).plot()?;
        let (ny, nx) = self.layout.shape();
        let (map_area, bar_area) =
            body.split_horizontally(2 * MARGIN + Y_LABEL + nx as u32 * self.cell_px());
        let (w, h) = (self.layout.width(), self.layout.height());
        let mut chart = ChartBuilder::on(&map_area)
            .margin(MARGIN)
            .x_label_area_size(X_LABEL)
            .y_label_area_size(Y_LABEL)
            .build_cartesian_2d(0.0..w, 0.0..h)
            .plot()?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("x (m)")
            .y_desc("y (m)")
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .label_style(text(13))
            .axis_desc_style(text(14))
            .draw()
            .plot()?;
        let half = 0.5 * self.layout.cell();
        let cells = (0..ny).flat_map(|j| (0..nx).map(move |i| (j, i)));
        chart
            .draw_series(cells.map(|(j, i)| {
                let (x, y) = self.layout.cell_centre(j, i);
                let v = self.field[[j, i]];
                let t = if self.plot.log {
                    v.max(1e-300).log10()
                } else {
                    v
                };
                let c = if self.layout.is_solid(j, i) {
                    OBSTACLE
                } else {
                    colour(&VIRIDIS, (t - self.lo) / (self.hi - self.lo))
                };
                Rectangle::new([(x - half, y - half), (x + half, y + half)], c.filled())
            }))
            .plot()?;
        let frame = Rectangle::new([(0.0, 0.0), (w, h)], BLACK.stroke_width(1));
        chart.plotting_area().draw(&frame).plot()?;
        if let Some(run) = &self.run {
            draw_run(&mut chart, run)?;
        }
        self.draw_colour_bar(&bar_area)
    }

    /// The colour bar: a linear axis over the scale (log10 of the values on a log scale, whole
    /// decades then), labelled with the values.
    fn draw_colour_bar<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        let (lo, hi, log) = (self.lo, self.hi, self.plot.log);
        let mut chart = ChartBuilder::on(area)
            .margin(MARGIN)
            .x_label_area_size(X_LABEL)
            .set_label_area_size(LabelAreaPosition::Right, BAR_LABEL)
            .build_cartesian_2d(0.0..1.0, lo..hi)
            .plot()?;
        let steps = 128;
        chart
            .draw_series((0..steps).map(|k| {
                let t = |k: i32| f64::from(k) / f64::from(steps);
                let (y0, y1) = (lo + t(k) * (hi - lo), lo + t(k + 1) * (hi - lo));
                let c = colour(&VIRIDIS, t(k) + 0.5 / f64::from(steps));
                Rectangle::new([(0.0, y0), (1.0, y1)], c.filled())
            }))
            .plot()?;
        chart
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_labels(if log { 5 } else { 6 })
            .y_desc(self.plot.unit.as_str())
            .label_style(text(13))
            .axis_desc_style(text(14))
            .y_label_formatter(&|v| tick_label(if log { 10f64.powf(*v) } else { *v }))
            .draw()
            .plot()
    }
}

/// A tick label: up to four significant digits from 10^-3 to 10^4, scientific otherwise.
pub(crate) fn tick_label(v: f64) -> String {
    if v != 0.0 && !(1e-3..1e4).contains(&v.abs()) {
        return format!("{v:.1e}").replace(".0e", "e");
    }
    let m = 10f64.powi(3 - v.abs().log10().floor().max(-4.0) as i32);
    format!("{}", (v * m).round() / m)
}
