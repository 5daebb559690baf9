//! Box plots of a study, like the paper's figure: one group per feature, one box per sensor.
//! Boxes span the quartiles with a line at the median; whiskers reach the furthest value within
//! 1.5 interquartile ranges; values beyond are drawn as dots.

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::Result;
use crate::report::field::tick_label;
use crate::report::{Plot, legend, text};
use crate::stats::BoxStats;

/// One group of boxes (a feature), each box a named sample (a sensor).
#[derive(Debug, Clone, PartialEq)]
pub struct BoxGroup {
    /// Group label under the axis.
    pub label: String,
    /// `(series name, values)` per box, in legend order.
    pub boxes: Vec<(String, Vec<f64>)>,
}

/// Box groups from `(group, series, value)` triples: groups and the series within each in the
/// order they first appear.
pub fn group_values(values: &[(String, String, f64)]) -> Vec<BoxGroup> {
    let mut groups: Vec<BoxGroup> = Vec::new();
    for (group, series, value) in values {
        let g = match groups.iter().position(|g| &g.label == group) {
            Some(g) => g,
            None => {
                groups.push(BoxGroup {
                    label: group.clone(),
                    boxes: Vec::new(),
                });
                groups.len() - 1
            }
        };
        let boxes = &mut groups[g].boxes;
        match boxes.iter_mut().find(|b| &b.0 == series) {
            Some(b) => b.1.push(*value),
            None => boxes.push((series.clone(), vec![*value])),
        }
    }
    groups
}

/// One panel of box plots: a title, a y axis from zero, one group per label on the x axis and
/// a legend of the series.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxPanel {
    /// Title above the plot.
    pub title: String,
    /// The y axis's description.
    pub y_desc: String,
    /// The groups, left to right.
    pub groups: Vec<BoxGroup>,
}

impl BoxPanel {
    pub(crate) fn draw<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        let all = self
            .groups
            .iter()
            .flat_map(|g| g.boxes.iter().flat_map(|b| &b.1));
        // Headroom above the highest value keeps the legend (upper left) off the boxes.
        let top = all
            .filter(|v| v.is_finite())
            .fold(1e-9_f64, |a, &b| a.max(b))
            * 1.5;
        let n = self.groups.len().max(1);
        let mut chart = ChartBuilder::on(area)
            .caption(&self.title, text(17))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..n as f64, 0.0..top)
            .plot()?;
        // Group labels sit at the groups' centres, k + 0.5.
        let label = |x: &f64| match self.groups.get((x - 0.5).round().max(0.0) as usize) {
            Some(g) if ((x - 0.5) - (x - 0.5).round()).abs() < 1e-9 => g.label.clone(),
            _ => String::new(),
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .light_line_style(WHITE)
            .bold_line_style(RGBColor(225, 225, 225))
            .x_labels(2 * n + 1)
            .x_label_formatter(&label)
            .y_label_formatter(&|v| tick_label(*v))
            .y_desc(self.y_desc.as_str())
            .label_style(text(13))
            .axis_desc_style(text(14))
            .draw()
            .plot()?;
        let mut series: Vec<&str> = Vec::new();
        for (g, group) in self.groups.iter().enumerate() {
            let nb = group.boxes.len().max(1) as f64;
            let w = (0.7 / nb).min(0.2);
            for (b, (name, values)) in group.boxes.iter().enumerate() {
                let Some(s) = BoxStats::of(values) else {
                    continue;
                };
                let [low, q1, median, q3, high] = s.five;
                let k = series
                    .iter()
                    .position(|n| n == name)
                    .unwrap_or(series.len());
                let new = k == series.len();
                if new {
                    series.push(name);
                }
                let c = colorous::TABLEAU10[k % colorous::TABLEAU10.len()];
                let fill = RGBColor(c.r, c.g, c.b);
                let cx = g as f64 + 0.5 + w * (b as f64 + 0.5 - 0.5 * nb);
                let (x0, x1) = (cx - 0.4 * w, cx + 0.4 * w);
                // Whiskers with caps from low to high; the box then covers their middle.
                let whiskers = ErrorBar::new_vertical(cx, low, median, high, BLACK, 10);
                chart.draw_series([whiskers]).plot()?;
                let boxed = chart
                    .draw_series([Rectangle::new([(x0, q1), (x1, q3)], fill.filled())])
                    .plot()?;
                if new {
                    boxed.label(name.as_str()).legend(move |(x, y)| {
                        Rectangle::new([(x, y - 5), (x + 12, y + 5)], fill.filled())
                    });
                }
                let outline = [(x0, q1), (x1, q1), (x1, q3), (x0, q3), (x0, q1)];
                let mid = [(x0, median), (x1, median)];
                let lines = [(&outline[..], 1), (&mid[..], 2)];
                let lines = lines.map(|(p, w)| PathElement::new(p.to_vec(), BLACK.stroke_width(w)));
                chart.draw_series(lines).plot()?;
                let dots = s
                    .outliers
                    .iter()
                    .map(|&v| Circle::new((cx, v), 2, BLACK.filled()));
                chart.draw_series(dots).plot()?;
            }
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)
    }
}
