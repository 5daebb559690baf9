//! Box plots of a study, like the paper's figure: one group per feature, one box per sensor.
//! Boxes span the quartiles with a line at the median; whiskers reach the furthest value within
//! 1.5 interquartile ranges; values beyond are drawn as dots.

use image::{Rgb, RgbImage};

use crate::report::{BLACK, WHITE, disc, draw_text, put};

const W: u32 = 960;
const H: u32 = 320;
const LEFT: u32 = 70;
const RIGHT: u32 = 20;
const TOP: u32 = 30;
const BOTTOM: u32 = 50;
const GRID: Rgb<u8> = Rgb([220, 220, 220]);

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

/// Quartiles by linear interpolation (the "type 7" rule of R and numpy).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let pos = q * (sorted.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    sorted[lo] + (pos - lo as f64) * (sorted[hi] - sorted[lo])
}

fn series_colour(k: usize) -> Rgb<u8> {
    let c = colorous::TABLEAU10[k % colorous::TABLEAU10.len()];
    Rgb([c.r, c.g, c.b])
}

fn fill_rect(img: &mut RgbImage, x0: i64, y0: i64, x1: i64, y1: i64, colour: Rgb<u8>) {
    for y in y0.min(y1)..=y0.max(y1) {
        for x in x0.min(x1)..=x0.max(x1) {
            put(img, (x, y), colour);
        }
    }
}

/// Renders one panel of box plots with a title and a labelled y axis starting at zero.
pub fn render_boxplots(title: &str, groups: &[BoxGroup]) -> RgbImage {
    let mut img = RgbImage::from_pixel(W, H, WHITE);
    draw_text(&mut img, LEFT, 8, title);
    let top_value = groups
        .iter()
        .flat_map(|g| g.boxes.iter().flat_map(|b| b.1.iter().copied()))
        .filter(|v| v.is_finite())
        .fold(0.0_f64, f64::max)
        .max(1e-9)
        * 1.05;
    let (plot_w, plot_h) = (W - LEFT - RIGHT, H - TOP - BOTTOM);
    let y_of =
        |v: f64| i64::from(TOP + plot_h) - (v / top_value * f64::from(plot_h)).round() as i64;
    for k in 0..=4 {
        let v = top_value * f64::from(k) / 4.0;
        let y = y_of(v);
        fill_rect(
            &mut img,
            i64::from(LEFT),
            y,
            i64::from(LEFT + plot_w),
            y,
            GRID,
        );
        draw_text(&mut img, 8, (y - 4).max(0) as u32, &format!("{v:.2}"));
    }
    let axis_bottom = i64::from(TOP + plot_h);
    fill_rect(
        &mut img,
        i64::from(LEFT),
        i64::from(TOP),
        i64::from(LEFT),
        axis_bottom,
        BLACK,
    );
    fill_rect(
        &mut img,
        i64::from(LEFT),
        axis_bottom,
        i64::from(LEFT + plot_w),
        axis_bottom,
        BLACK,
    );
    let group_w = f64::from(plot_w) / groups.len().max(1) as f64;
    let mut legend: Vec<String> = Vec::new();
    for (g, group) in groups.iter().enumerate() {
        let gx = f64::from(LEFT) + g as f64 * group_w;
        let nb = group.boxes.len().max(1) as f64;
        let box_w = (group_w * 0.7 / nb).min(40.0);
        for (b, (name, values)) in group.boxes.iter().enumerate() {
            if !legend.contains(name) {
                legend.push(name.clone());
            }
            let colour = series_colour(legend.iter().position(|n| n == name).unwrap_or(0));
            let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
            if v.is_empty() {
                continue;
            }
            v.sort_by(f64::total_cmp);
            let (q1, med, q3) = (quantile(&v, 0.25), quantile(&v, 0.5), quantile(&v, 0.75));
            let iqr = q3 - q1;
            let lo = v
                .iter()
                .copied()
                .find(|&x| x >= q1 - 1.5 * iqr)
                .unwrap_or(q1);
            let hi = v
                .iter()
                .rev()
                .copied()
                .find(|&x| x <= q3 + 1.5 * iqr)
                .unwrap_or(q3);
            let cx = gx + group_w * 0.15 + box_w * (b as f64 + 0.5);
            let (x0, x1) = ((cx - box_w * 0.4) as i64, (cx + box_w * 0.4) as i64);
            let xm = cx as i64;
            fill_rect(&mut img, xm, y_of(lo), xm, y_of(q1), BLACK);
            fill_rect(&mut img, xm, y_of(q3), xm, y_of(hi), BLACK);
            fill_rect(&mut img, xm - 4, y_of(lo), xm + 4, y_of(lo), BLACK);
            fill_rect(&mut img, xm - 4, y_of(hi), xm + 4, y_of(hi), BLACK);
            fill_rect(&mut img, x0, y_of(q3), x1, y_of(q1), colour);
            fill_rect(&mut img, x0, y_of(med), x1, y_of(med), BLACK);
            for &x in v.iter().filter(|&&x| x < lo || x > hi) {
                disc(&mut img, (xm, y_of(x)), 2, BLACK);
            }
        }
        let label_x = (gx + group_w / 2.0 - 4.0 * group.label.len() as f64).max(0.0) as u32;
        draw_text(&mut img, label_x, TOP + plot_h + 8, &group.label);
    }
    let mut lx = LEFT;
    for (k, name) in legend.iter().enumerate() {
        fill_rect(
            &mut img,
            i64::from(lx),
            i64::from(H - 18),
            i64::from(lx + 12),
            i64::from(H - 8),
            series_colour(k),
        );
        draw_text(&mut img, lx + 18, H - 17, name);
        lx += 30 + 8 * name.len() as u32;
    }
    img
}
