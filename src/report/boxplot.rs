//! Box plots of a study, like the paper's figure: one group per feature, one box per sensor.
//! Boxes span the quartiles with a line at the median; whiskers reach the furthest value within
//! 1.5 interquartile ranges; values beyond are drawn as dots.

use indexmap::{IndexMap, IndexSet};
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::Result;
use crate::report::{legend, text};
use crate::stats::BoxStats;

/// The values of each box (a series, e.g. a sensor) in each group (e.g. a feature), groups and
/// the series within each in the order they first appear.
pub type BoxGroups = IndexMap<String, IndexMap<String, Vec<f64>>>;

/// Box groups from `(group, series, value)` triples.
pub fn group_values(values: &[(String, String, f64)]) -> BoxGroups {
    let mut groups = BoxGroups::new();
    for (group, series, value) in values {
        let group = groups.entry(group.clone()).or_default();
        group.entry(series.clone()).or_default().push(*value);
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
    pub groups: BoxGroups,
}

impl BoxPanel {
    pub(crate) fn draw<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        let boxes = self.groups.values().flat_map(IndexMap::values);
        let values = boxes.flatten().copied();
        // Headroom above the highest value keeps the legend (upper left) off the boxes.
        let top = 1.5 * values.filter(|v| v.is_finite()).fold(1e-9, f64::max);
        let n = self.groups.len().max(1);
        let mut chart = ChartBuilder::on(area)
            .caption(&self.title, text(17))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..n as f64, 0.0..top)?;
        // Group labels sit at the groups' centres, k + 0.5.
        let label = |x: &f64| match self.groups.get_index(*x as usize) {
            Some((label, _)) if (x.fract() - 0.5).abs() < 1e-9 => label.clone(),
            _ => String::new(),
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .light_line_style(WHITE)
            .bold_line_style(RGBColor(225, 225, 225))
            .x_labels(2 * n + 1)
            .x_label_formatter(&label)
            .y_desc(self.y_desc.as_str())
            .label_style(text(13))
            .axis_desc_style(text(14))
            .draw()?;
        let mut series = IndexSet::new();
        for (g, boxes) in self.groups.values().enumerate() {
            let nb = boxes.len().max(1) as f64;
            let w = (0.7 / nb).min(0.2);
            for (b, (name, values)) in boxes.iter().enumerate() {
                let Some(s) = BoxStats::of(values) else {
                    continue;
                };
                let [low, q1, median, q3, high] = s.five;
                let (k, new) = series.insert_full(name.as_str());
                let c = colorous::TABLEAU10[k % colorous::TABLEAU10.len()];
                let fill = RGBColor(c.r, c.g, c.b).filled();
                let cx = g as f64 + 0.5 + w * (b as f64 + 0.5 - 0.5 * nb);
                let (x0, x1) = (cx - 0.4 * w, cx + 0.4 * w);
                // Whiskers with caps from low to high; the box then covers their middle.
                let whiskers = ErrorBar::new_vertical(cx, low, median, high, BLACK, 10);
                chart.draw_series([whiskers])?;
                let rect = [(x0, q1), (x1, q3)];
                let boxed = chart.draw_series([Rectangle::new(rect, fill)])?;
                if new {
                    let key = move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], fill);
                    boxed.label(name.as_str()).legend(key);
                }
                let area = chart.plotting_area();
                area.draw(&Rectangle::new(rect, BLACK))?;
                let mid = PathElement::new([(x0, median), (x1, median)], BLACK.stroke_width(2));
                area.draw(&mid)?;
                for &v in &s.outliers {
                    area.draw(&Circle::new((cx, v), 2, BLACK.filled()))?;
                }
            }
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)
    }
}
