//! Figures drawn with `plotters`: fields over the arena ([`field`]), STE beliefs ([`belief`]) and
//! the study's box plots ([`boxplot`]), with axes in metres, ticks, titles, labelled colour bars
//! and legends; written as PNG, or as SVG when the file name ends in `.svg`.
//!
//! Text is DejaVu Sans, embedded by the `dejavu` crate and rasterised by ab_glyph: a machine
//! without system fonts draws the same pictures.

use std::path::Path;
use std::sync::Once;

use image::ImageEncoder;
use plotters::coord::{CoordTranslate, Shift};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use crate::error::{Error, Result};
use crate::io;

pub mod belief;
pub mod boxplot;
pub mod field;

pub use field::{FieldPanel, FieldPlot, LOG_DECADES};

/// The font family of every figure.
pub const FONT: &str = "sans-serif";

/// One panel of a figure; a figure stacks its panels top to bottom.
#[derive(Debug, Clone)]
pub enum Panel<'a> {
    /// A field over the arena with a colour bar (and perhaps a run on top, [`belief`]).
    Field(FieldPanel<'a>),
    /// Box plots of a study.
    Boxes(boxplot::BoxPanel),
}

impl Panel<'_> {
    fn size(&self) -> (u32, u32) {
        match self {
            Self::Field(p) => p.size(),
            Self::Boxes(_) => (960, 340),
        }
    }

    fn draw<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<()> {
        match self {
            Self::Field(p) => p.draw(area),
            Self::Boxes(p) => p.draw(area),
        }
    }
}

/// Writes a figure atomically: SVG when the path ends in `.svg`, PNG otherwise.
///
/// # Errors
/// [`Error::Parameter`] when a panel cannot be drawn, [`Error::Image`] when encoding fails,
/// [`Error::Io`] when the file cannot be written.
pub fn save_figure(panels: &[Panel<'_>], path: &Path) -> Result<()> {
    static FONTS: Once = Once::new();
    FONTS.call_once(|| {
        // Valid TrueType bytes shipped by `dejavu`; were they not, text would be missing, which
        // the figure tests would catch.
        let _ = register_font(FONT, FontStyle::Normal, dejavu::sans::regular());
    });
    let w = panels.iter().map(|p| p.size().0).max().unwrap_or(1);
    let h = panels.iter().map(|p| p.size().1).sum::<u32>().max(1);
    let svg = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    io::write_atomic(path, |out| {
        if svg {
            let mut doc = String::new();
            draw(
                SVGBackend::with_string(&mut doc, (w, h)).into_drawing_area(),
                panels,
            )?;
            out.extend_from_slice(doc.as_bytes());
            return Ok(());
        }
        let mut rgb = vec![255u8; w as usize * h as usize * 3];
        draw(
            BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area(),
            panels,
        )?;
        image::codecs::png::PngEncoder::new(out)
            .write_image(&rgb, w, h, image::ExtendedColorType::Rgb8)
            .map_err(|e| Error::Image {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })
    })
}

/// Draws panels top to bottom on white.
fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, panels: &[Panel<'_>]) -> Result<()> {
    root.fill(&WHITE).plot()?;
    let mut rest = root;
    for panel in panels {
        let (top, bottom) = rest.split_vertically(panel.size().1);
        panel.draw(&top)?;
        rest = bottom;
    }
    rest.present().plot()
}

/// Plotters' drawing errors as ours.
trait Plot<T> {
    fn plot(self) -> Result<T>;
}

impl<T, E: std::error::Error + Send + Sync> Plot<T>
    for std::result::Result<T, DrawingAreaErrorKind<E>>
{
    fn plot(self) -> Result<T> {
        self.map_err(|e| Error::Parameter(format!("cannot draw the figure: {e}")))
    }
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
        .draw()
        .plot()
}

/// Black text of `size` pixels.
fn text(size: u32) -> TextStyle<'static> {
    (FONT, size).into_font().color(&BLACK)
}
