//! Line charts on the unit square, such as a reliability diagram: nominal against actual
//! coverage of credible regions, or a histogram of the levels at which the regions first hold
//! the source; one line a series, with the ideal as a dashed reference.

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::Result;
use crate::report::{legend, text};

/// One panel of lines over `[0, 1]` on x.
#[derive(Debug, Clone, PartialEq)]
pub struct CurvePanel {
    /// Title above the plot.
    pub title: String,
    /// The x axis's description.
    pub x_desc: String,
    /// The y axis's description.
    pub y_desc: String,
    /// The y axis's top (it starts at 0).
    pub y_max: f64,
    /// The ideal, drawn dashed: `(label, points)`.
    pub ideal: (String, Vec<(f64, f64)>),
    /// The series: `(label, points)`, in legend order.
    pub series: Vec<(String, Vec<(f64, f64)>)>,
}

impl CurvePanel {
    pub(crate) fn draw<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        let mut chart = ChartBuilder::on(area)
            .caption(&self.title, text(17))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..1.0, 0.0..self.y_max)?;
        chart
            .configure_mesh()
            .light_line_style(WHITE)
            .bold_line_style(RGBColor(225, 225, 225))
            .x_desc(self.x_desc.as_str())
            .y_desc(self.y_desc.as_str())
            .label_style(text(13))
            .axis_desc_style(text(14))
            .draw()?;
        let grey = RGBColor(120, 120, 120);
        let (name, points) = &self.ideal;
        chart
            .draw_series(DashedLineSeries::new(
                points.iter().copied(),
                6,
                4,
                grey.stroke_width(2),
            ))?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], grey.stroke_width(2)));
        for (k, (name, points)) in self.series.iter().enumerate() {
            let c = colorous::TABLEAU10[k % colorous::TABLEAU10.len()];
            let colour = RGBColor(c.r, c.g, c.b);
            chart
                .draw_series(LineSeries::new(
                    points.iter().copied(),
                    colour.stroke_width(2),
                ))?
                .label(name.as_str())
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 16, y)], colour.stroke_width(3))
                });
            chart.draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled())))?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)
    }
}
