//! Figures drawn with `plotters`: fields over the arena ([`field`]), STE beliefs ([`belief`]),
//! the study's box plots ([`boxplot`]) and reliability diagrams ([`curves`]); PNG, or SVG when the file name ends in `.svg`. Text is
//! DejaVu Sans, embedded by the `dejavu` crate: no system fonts needed. Tables are Markdown
//! ([`markdown_table`]).

use std::path::Path;
use std::sync::Once;

use dejavu::sans;
use image::ImageEncoder;
use plotters::coord::{CoordTranslate, Shift};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use crate::error::{Error, Result};
use crate::io;

pub mod belief;
pub mod boxplot;
pub mod curves;
pub mod field;

pub use field::{FieldPanel, FieldPlot, LOG_DECADES};

/// A Markdown table: the header row, its rule, then one line per row of cells.
pub fn markdown_table(header: &[&str], rows: impl IntoIterator<Item = Vec<String>>) -> String {
    let line = |cells: &[String]| format!("| {} |\n", cells.join(" | "));
    let head: Vec<String> = header.iter().map(|h| h.to_string()).collect();
    let mut t = line(&head);
    t.push_str(&format!("|{}\n", "---|".repeat(header.len())));
    for row in rows {
        t.push_str(&line(&row));
    }
    t
}

/// The font family of every figure.
pub const FONT: &str = "sans-serif";

/// One panel of a figure; a figure stacks its panels top to bottom.
#[derive(Debug, Clone)]
pub enum Panel<'a> {
    /// A field over the arena with a colour bar (and perhaps a run on top, [`belief`]).
    Field(FieldPanel<'a>),
    /// Box plots of a study.
    Boxes(boxplot::BoxPanel),
    /// Lines over `[0, 1]`, such as a reliability diagram.
    Curves(curves::CurvePanel),
}

impl Panel<'_> {
    fn size(&self) -> (u32, u32) {
        match self {
            Self::Field(p) => p.size(),
            Self::Boxes(_) => (960, 340),
            Self::Curves(_) => (640, 400),
        }
    }

    fn draw<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        match self {
            Self::Field(p) => p.draw(area),
            Self::Boxes(p) => p.draw(area),
            Self::Curves(p) => p.draw(area),
        }
    }
}

/// Writes a figure atomically: SVG when the path ends in `.svg`, PNG otherwise.
///
/// # Errors
/// [`Error::Figure`] when a panel cannot be drawn, [`Error::Image`] when encoding fails,
/// [`Error::Io`] when the file cannot be written.
pub fn save_figure(panels: &[Panel<'_>], path: &Path) -> Result<()> {
    static FONTS: Once = Once::new();
    // `dejavu` ships valid TrueType bytes; were they not, the figure tests would miss the text.
    FONTS.call_once(|| register_font(FONT, FontStyle::Normal, sans::regular()).unwrap_or(()));
    let w = panels.iter().map(|p| p.size().0).max().unwrap_or(1);
    let h = panels.iter().map(|p| p.size().1).sum::<u32>().max(1);
    io::write_atomic(path, |out| {
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("svg"))
        {
            let mut doc = String::new();
            draw(SVGBackend::with_string(&mut doc, (w, h)), panels)?;
            out.extend_from_slice(doc.as_bytes());
            return Ok(());
        }
        let mut rgb = vec![255u8; w as usize * h as usize * 3];
        draw(BitMapBackend::with_buffer(&mut rgb, (w, h)), panels)?;
        let png = image::codecs::png::PngEncoder::new(out);
        png.write_image(&rgb, w, h, image::ExtendedColorType::Rgb8)
            .map_err(|e| Error::Image {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })
    })
}

/// Draws panels top to bottom on white.
fn draw<DB: DrawingBackend>(backend: DB, panels: &[Panel<'_>]) -> Result<()> {
    let mut rest = backend.into_drawing_area();
    rest.fill(&WHITE)?;
    for panel in panels {
        let (top, bottom) = rest.split_vertically(panel.size().1);
        panel.draw(&top)?;
        rest = bottom;
    }
    Ok(rest.present()?)
}

/// The colour of `t` in `[0, 1]` on a colour map (for example `colorous::VIRIDIS`).
pub fn colour(map: &colorous::Gradient, t: f64) -> RGBColor {
    let c = map.eval_continuous(t.clamp(0.0, 1.0));
    RGBColor(c.r, c.g, c.b)
}

/// Draws the legend of a chart's labelled series at `position`.
fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(text(12))
        .draw()?;
    Ok(())
}

/// Black text of `size` pixels.
fn text(size: u32) -> TextStyle<'static> {
    (FONT, size).into_font().color(&BLACK)
}
