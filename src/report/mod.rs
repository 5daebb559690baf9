//! PNG pictures: a field over the arena with obstacles, a perceptual colour map (viridis),
//! optional log scale, and a labelled colour bar.

use std::path::Path;

use font8x8::UnicodeFonts;
use image::{ImageEncoder, Rgb, RgbImage};
use ndarray::Array2;

use crate::error::{Error, Result};
use crate::io;
use crate::layout::Layout;

pub mod belief;
pub mod boxplot;

/// Decades shown below the maximum on a log scale.
pub const LOG_DECADES: f64 = 4.0;

pub(crate) const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
pub(crate) const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const OBSTACLE: Rgb<u8> = Rgb([90, 90, 90]);
const MARGIN: u32 = 12;
const TITLE_H: u32 = 28;
const BAR_W: u32 = 18;
const LABEL_W: u32 = 90;

/// How to draw a field.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldPlot {
    /// Title printed above the map.
    pub title: String,
    /// Logarithmic colour scale over [`LOG_DECADES`] decades below the maximum.
    pub log: bool,
    /// Unit shown next to the colour bar.
    pub unit: String,
}

/// Where the map of a rendered field lies in its image, to draw on top of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapFrame {
    left: u32,
    top: u32,
    scale: u32,
    cell: f64,
    height: u32,
}

impl MapFrame {
    /// Pixel of a point in metres (may lie outside the image for points outside the arena).
    pub fn pixel(&self, x: f64, y: f64) -> (i64, i64) {
        let s = f64::from(self.scale) / self.cell;
        (
            i64::from(self.left) + (x * s).round() as i64,
            i64::from(self.top + self.height) - (y * s).round() as i64,
        )
    }
}

/// Renders a `[ny, nx]` field with `y` pointing up, obstacles in grey.
///
/// # Errors
/// [`Error::Parameter`] when the field's shape is not the layout's grid or it holds NaN.
pub fn render_field(field: &Array2<f64>, layout: &Layout, plot: &FieldPlot) -> Result<RgbImage> {
    render_field_framed(field, layout, plot).map(|(img, _)| img)
}

/// [`render_field`], also returning where the map lies so that markers can be drawn on it.
///
/// # Errors
/// As [`render_field`].
pub fn render_field_framed(
    field: &Array2<f64>,
    layout: &Layout,
    plot: &FieldPlot,
) -> Result<(RgbImage, MapFrame)> {
    let (ny, nx) = layout.shape();
    if field.dim() != (ny, nx) {
        return Err(Error::Parameter(format!(
            "field shape {:?} does not match the layout grid {:?}",
            field.dim(),
            (ny, nx)
        )));
    }
    if field.iter().any(|v| v.is_nan()) {
        return Err(Error::Parameter("field contains NaN".into()));
    }
    let scale = (960 / nx as u32).clamp(2, 16);
    let (map_w, map_h) = (nx as u32 * scale, ny as u32 * scale);
    let width = MARGIN * 3 + map_w + BAR_W + LABEL_W;
    let height = TITLE_H + map_h + MARGIN * 2;
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    draw_text(&mut img, MARGIN, 8, &plot.title);

    let vmax = field.iter().copied().fold(0.0_f64, f64::max);
    let vmin = field.iter().copied().fold(f64::INFINITY, f64::min).min(0.0);
    let (lo, hi) = if plot.log {
        let top = if vmax > 0.0 { vmax.log10() } else { 0.0 };
        (top - LOG_DECADES, top)
    } else {
        (vmin, if vmax > vmin { vmax } else { vmin + 1.0 })
    };
    let to_unit = |v: f64| -> f64 {
        let t = if plot.log { v.max(1e-300).log10() } else { v };
        ((t - lo) / (hi - lo)).clamp(0.0, 1.0)
    };
    for j in 0..ny {
        for i in 0..nx {
            let colour = if layout.is_solid(j, i) {
                OBSTACLE
            } else {
                viridis(to_unit(field[[j, i]]))
            };
            let (x0, y0) = (
                MARGIN + i as u32 * scale,
                TITLE_H + (ny - 1 - j) as u32 * scale,
            );
            fill(&mut img, x0, y0, scale, scale, colour);
        }
    }
    frame(&mut img, MARGIN - 1, TITLE_H - 1, map_w + 2, map_h + 2);

    let bar_x = MARGIN * 2 + map_w;
    for row in 0..map_h {
        let t = 1.0 - f64::from(row) / f64::from(map_h - 1);
        fill(&mut img, bar_x, TITLE_H + row, BAR_W, 1, viridis(t));
    }
    frame(&mut img, bar_x - 1, TITLE_H - 1, BAR_W + 2, map_h + 2);
    let label = |t: f64| {
        let v = lo + t * (hi - lo);
        if plot.log {
            format!("{:.1e}", 10f64.powf(v))
        } else {
            format!("{v:.3e}")
        }
    };
    let text_x = bar_x + BAR_W + 6;
    draw_text(&mut img, text_x, TITLE_H, &label(1.0));
    draw_text(&mut img, text_x, TITLE_H + map_h / 2 - 4, &label(0.5));
    draw_text(&mut img, text_x, TITLE_H + map_h - 8, &label(0.0));
    if map_h > 48 {
        draw_text(&mut img, text_x, TITLE_H + map_h / 4 - 4, &plot.unit);
    }
    let frame = MapFrame {
        left: MARGIN,
        top: TITLE_H,
        scale,
        cell: layout.cell(),
        height: map_h,
    };
    Ok((img, frame))
}

/// Sets a pixel if it lies in the image.
pub fn put(img: &mut RgbImage, (x, y): (i64, i64), colour: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, colour);
    }
}

/// A filled disc of radius `r` pixels.
pub fn disc(img: &mut RgbImage, (cx, cy): (i64, i64), r: i64, colour: Rgb<u8>) {
    for dy in -r..=r {
        for dx in -r..=r {
            if dx * dx + dy * dy <= r * r {
                put(img, (cx + dx, cy + dy), colour);
            }
        }
    }
}

/// Writes an image as PNG, atomically.
///
/// # Errors
/// [`Error::Image`] when encoding fails, [`Error::Io`] when the file cannot be written.
pub fn save_png(img: &RgbImage, path: &Path) -> Result<()> {
    io::write_atomic(path, |buf| {
        image::codecs::png::PngEncoder::new(buf)
            .write_image(
                img.as_raw(),
                img.width(),
                img.height(),
                image::ExtendedColorType::Rgb8,
            )
            .map_err(|e| Error::Image {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })
    })
}

/// The viridis colour of `t` in `[0, 1]`.
pub fn viridis(t: f64) -> Rgb<u8> {
    let c = colorous::VIRIDIS.eval_continuous(t);
    Rgb([c.r, c.g, c.b])
}

fn fill(img: &mut RgbImage, x0: u32, y0: u32, w: u32, h: u32, colour: Rgb<u8>) {
    for y in y0..(y0 + h).min(img.height()) {
        for x in x0..(x0 + w).min(img.width()) {
            img.put_pixel(x, y, colour);
        }
    }
}

fn frame(img: &mut RgbImage, x0: u32, y0: u32, w: u32, h: u32) {
    fill(img, x0, y0, w, 1, BLACK);
    fill(img, x0, y0 + h - 1, w, 1, BLACK);
    fill(img, x0, y0, 1, h, BLACK);
    fill(img, x0 + w - 1, y0, 1, h, BLACK);
}

/// Draws text with the public-domain 8x8 bitmap font (no system fonts needed).
pub fn draw_text(img: &mut RgbImage, x0: u32, y0: u32, text: &str) {
    for (k, ch) in text.chars().enumerate() {
        let Some(glyph) = font8x8::BASIC_FONTS.get(ch) else {
            continue;
        };
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits & (1 << col) != 0 {
                    let (x, y) = (x0 + k as u32 * 8 + col, y0 + row as u32);
                    if x < img.width() && y < img.height() {
                        img.put_pixel(x, y, BLACK);
                    }
                }
            }
        }
    }
}

/// Stacks images top to bottom on a white background (for side-by-side comparisons).
pub fn stack_vertical(images: &[RgbImage]) -> RgbImage {
    let width = images.iter().map(RgbImage::width).max().unwrap_or(1);
    let height = images.iter().map(RgbImage::height).sum::<u32>().max(1);
    let mut out = RgbImage::from_pixel(width, height, WHITE);
    let mut top = 0;
    for img in images {
        for (x, y, p) in img.enumerate_pixels() {
            out.put_pixel(x, top + y, *p);
        }
        top += img.height();
    }
    out
}
