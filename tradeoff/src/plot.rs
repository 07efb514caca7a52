//! RMSE (log) against frame time (log): one colour per knob, each point labelled with its
//! value, the presets by name, the Pareto front as a line and, when measured, Mitsuba's
//! curve (its relative RMSE on stagehand's scale). Written as PNG and SVG with plotters and
//! the vendored DejaVu Sans (pure Rust: no fontconfig or FreeType).

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

use super::TradeoffError;
use super::peer::PeerPoint;
use super::sweep::{Point, Tradeoff};

/// DejaVu Sans (licence in `tradeoff/assets/DejaVuSans-LICENSE.txt`).
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
const FAMILY: &str = "sans-serif";
/// Plot size in pixels (PNG) and user units (SVG).
pub const SIZE: (u32, u32) = (1200, 800);

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The vendored font is a valid TrueType file; on failure text is simply not drawn.
        let _ = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT);
    });
}

/// Colour of a knob's points.
fn colour(knob: &str) -> RGBColor {
    match knob {
        "preset" => RGBColor(0, 0, 0),
        "spp_side" => RGBColor(31, 119, 180),
        "halogen_samples" => RGBColor(255, 127, 14),
        "relief_mm" => RGBColor(44, 160, 44),
        "shadow_maps" => RGBColor(214, 39, 40),
        "bounces" => RGBColor(148, 103, 189),
        "bounce_rays" => RGBColor(140, 86, 75),
        "dipole_samples" => RGBColor(227, 119, 194),
        "tube_samples" => RGBColor(23, 190, 207),
        _ => RGBColor(127, 127, 127),
    }
}

/// A tick label with at most three significant digits and no trailing zeros.
fn short(v: f64) -> String {
    let digits = (2 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// A drawing call of plotters that failed (its error type depends on the backend).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct DrawError(String);

/// Mitsuba's colour.
const PEER: RGBColor = RGBColor(188, 189, 34);

/// What goes on the plot.
struct Data<'a> {
    title: String,
    points: &'a [Point],
    peer: Option<Vec<(f64, f64, u32)>>,
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, d: &Data<'_>) -> Result<(), DrawError>
where
    DB::ErrorType: 'static,
{
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| DrawError(x.to_string());
    root.fill(&WHITE).map_err(e)?;
    let finite = |v: f64| v.is_finite() && v > 0.0;
    let mut ts: Vec<f64> = d
        .points
        .iter()
        .map(|p| p.time_s)
        .filter(|&v| finite(v))
        .collect();
    let mut rs: Vec<f64> = d
        .points
        .iter()
        .map(|p| p.error.rmse)
        .filter(|&v| finite(v))
        .collect();
    if let Some(peer) = &d.peer {
        ts.extend(peer.iter().map(|p| p.0).filter(|&v| finite(v)));
        rs.extend(peer.iter().map(|p| p.1).filter(|&v| finite(v)));
    }
    let lo_hi = |v: &[f64], default: (f64, f64)| {
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(0.0, f64::max);
        if lo.is_finite() && hi > 0.0 {
            (lo / 1.6, hi * 1.6)
        } else {
            default
        }
    };
    let (t0, t1) = lo_hi(&ts, (1e-3, 1.0));
    let (r0, r1) = lo_hi(&rs, (1e-5, 1.0));
    // Zero error (identical to the reference) sits on the bottom edge.
    let y = |r: f64| if finite(r) { r } else { r0 };
    let mut chart = ChartBuilder::on(&root)
        .caption(&d.title, (FAMILY, 24))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d((t0..t1).log_scale(), (r0..r1).log_scale())
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("frame time, s (log)")
        .y_desc("RMSE vs converged reference (log)")
        .label_style((FAMILY, 14))
        .axis_desc_style((FAMILY, 16))
        .x_labels(12)
        .y_labels(12)
        .light_line_style(RGBColor(235, 235, 235))
        .x_label_formatter(&|v| short(*v))
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .draw()
        .map_err(e)?;
    let mut front: Vec<&Point> = d.points.iter().filter(|p| p.pareto).collect();
    front.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
    chart
        .draw_series(LineSeries::new(
            front.iter().map(|p| (p.time_s, y(p.error.rmse))),
            BLACK.stroke_width(2),
        ))
        .map_err(e)?
        .label("Pareto front")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
    let mut knobs: Vec<&str> = Vec::new();
    for p in d.points {
        if !knobs.contains(&p.setting.knob.as_str()) {
            knobs.push(&p.setting.knob);
        }
    }
    for knob in knobs {
        let c = colour(knob);
        let pts: Vec<&Point> = d.points.iter().filter(|p| p.setting.knob == knob).collect();
        chart
            .draw_series(pts.iter().map(|p| {
                let label = p.setting.value.clone();
                let size = if p.pareto { 6 } else { 4 };
                let font = (FAMILY, if knob == "preset" { 15 } else { 12 })
                    .into_font()
                    .color(&c);
                EmptyElement::at((p.time_s, y(p.error.rmse)))
                    + Circle::new((0, 0), size, c.filled())
                    + Text::new(label, (7, -14), font)
            }))
            .map_err(e)?
            .label(knob)
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, c.filled()));
    }
    if let Some(peer) = &d.peer {
        chart
            .draw_series(LineSeries::new(
                peer.iter().map(|&(t, r, _)| (t, y(r))),
                PEER.stroke_width(2),
            ))
            .map_err(e)?
            .label("Mitsuba 3 (spp)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], PEER.stroke_width(2)));
        chart
            .draw_series(peer.iter().map(|&(t, r, spp)| {
                EmptyElement::at((t, y(r)))
                    + TriangleMarker::new((0, 0), 6, PEER.filled())
                    + Text::new(
                        format!("{spp}"),
                        (7, 4),
                        (FAMILY, 12).into_font().color(&PEER),
                    )
            }))
            .map_err(e)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FAMILY, 14))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}

/// Writes `tradeoff.png` and `tradeoff.svg` into `dir`; `peer` adds Mitsuba's curve (its
/// relative RMSE times stagehand's reference mean).
pub fn write(dir: &Path, t: &Tradeoff, peer: Option<&[PeerPoint]>) -> Result<(), TradeoffError> {
    register_font();
    let data = Data {
        title: format!(
            "{}: RMSE vs frame time, {} {}×{} (black line: Pareto front)",
            t.setup.options.scene, t.setup.camera, t.setup.options.width, t.setup.options.height
        ),
        points: &t.points,
        peer: peer.map(|pts| {
            pts.iter()
                .map(|p| (p.time_s, p.rel_rmse * t.reference_mean, p.spp))
                .collect()
        }),
    };
    let png = dir.join("tradeoff.png");
    draw(BitMapBackend::new(&png, SIZE).into_drawing_area(), &data)
        .map_err(|e| TradeoffError::io(&png, e))?;
    let svg = dir.join("tradeoff.svg");
    draw(SVGBackend::new(&svg, SIZE).into_drawing_area(), &data)
        .map_err(|e| TradeoffError::io(&svg, e))?;
    Ok(())
}
