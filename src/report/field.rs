//! A field over the arena: a viridis colour map (linear, or logarithmic over [`LOG_DECADES`]
//! decades below the maximum), obstacles in grey, axes in metres, a title and a colour bar
//! labelled in the field's unit.

use std::ops::Range;

use colorous::VIRIDIS;
use ndarray::Array2;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::report::belief::{BeliefPlot, draw_run};
use crate::report::{colour, text};

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
    /// The field on the colour scale: log10 of the values on a log scale.
    scaled: Array2<f64>,
    layout: &'a Layout,
    plot: FieldPlot,
    /// A run drawn on top (see [`crate::report::belief`]).
    pub(crate) run: Option<Box<BeliefPlot<'a>>>,
    /// The colour scale's bounds.
    range: Range<f64>,
}

impl<'a> FieldPanel<'a> {
    /// A `[ny, nx]` field on the layout's grid.
    ///
    /// # Errors
    /// [`Error::Parameter`] when the field's shape is not the layout's grid or it holds NaN.
    pub fn new(mut field: Array2<f64>, layout: &'a Layout, plot: FieldPlot) -> Result<Self> {
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
        let hi = field.fold(0.0_f64, |a, &v| a.max(v));
        let range = if plot.log {
            field.mapv_inplace(|v| v.max(1e-300).log10());
            let top = if hi > 0.0 { hi.log10() } else { 0.0 };
            top - LOG_DECADES..top
        } else {
            let lo = field.fold(0.0_f64, |a, &v| a.min(v));
            lo..if hi > lo { hi } else { lo + 1.0 }
        };
        Ok(Self {
            scaled: field,
            layout,
            plot,
            run: None,
            range,
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

    /// The colour of a scaled value.
    fn colour(&self, v: f64) -> RGBColor {
        let Range { start, end } = self.range;
        colour(&VIRIDIS, (v - start) / (end - start))
    }

    pub(crate) fn draw<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        let (title, body) = area.split_vertically(TITLE_H);
        let at = ((MARGIN + Y_LABEL) as i32, 8);
        title.draw_text(&self.plot.title, &text(17), at)?;
        let map_w = 2 * MARGIN + Y_LABEL + self.layout.shape().1 as u32 * self.cell_px();
        let (map_area, bar_area) = body.split_horizontally(map_w);
        let (w, h) = (self.layout.width(), self.layout.height());
        let mut chart = ChartBuilder::on(&map_area)
            .margin(MARGIN)
            .x_label_area_size(X_LABEL)
            .y_label_area_size(Y_LABEL)
            .build_cartesian_2d(0.0..w, 0.0..h)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("x (m)")
            .y_desc("y (m)")
            .label_style(text(13))
            .axis_desc_style(text(14))
            .draw()?;
        let half = 0.5 * self.layout.cell();
        let cells = self.scaled.indexed_iter().map(|((j, i), &v)| {
            let (x, y) = self.layout.cell_centre(j, i);
            let c = if self.layout.is_solid(j, i) {
                OBSTACLE
            } else {
                self.colour(v)
            };
            Rectangle::new([(x - half, y - half), (x + half, y + half)], c.filled())
        });
        chart.draw_series(cells)?;
        let frame = Rectangle::new([(0.0, 0.0), (w, h)], BLACK.stroke_width(1));
        chart.plotting_area().draw(&frame)?;
        if let Some(run) = &self.run {
            draw_run(&mut chart, run)?;
        }
        self.draw_colour_bar(&bar_area)
    }

    /// The colour bar: a linear axis over the scale (log10 of the values on a log scale, whole
    /// decades then), labelled with the values.
    fn draw_colour_bar<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        let Range { start, end } = self.range;
        let mut chart = ChartBuilder::on(area)
            .margin(MARGIN)
            .x_label_area_size(X_LABEL)
            .set_label_area_size(LabelAreaPosition::Right, BAR_LABEL)
            .build_cartesian_2d(0.0..1.0, start..end)?;
        let step = (end - start) / 128.0;
        let bands = (0..128).map(|k| start + f64::from(k) * step);
        let fill = |y: f64| self.colour(y + 0.5 * step).filled();
        chart.draw_series(bands.map(|y| Rectangle::new([(0.0, y), (1.0, y + step)], fill(y))))?;
        let log = self.plot.log;
        chart
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_labels(if log { 5 } else { 6 })
            .y_desc(self.plot.unit.as_str())
            .label_style(text(13))
            .axis_desc_style(text(14))
            .y_label_formatter(&|v| tick_label(if log { 10f64.powf(*v) } else { *v }))
            .draw()?;
        Ok(())
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
