//! Line plots to PNG (plotters with an embedded DejaVu Sans font, so no system fonts are
//! needed). Used for the paper's Fig. 7 (error versus number of components).

use anyhow::{Context, Result};
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// One named series of (x, y) points.
pub struct Series {
    /// Legend label.
    pub name: String,
    /// Points, in drawing order.
    pub points: Vec<(f64, f64)>,
}

/// A grid of line plots (one panel per `(title, y label, series)`), sharing the x label, with
/// a logarithmic x axis when `log_x`; written atomically to `path` as PNG.
pub fn line_panels(
    path: &Path,
    panels: &[(String, String, Vec<Series>)],
    x_label: &str,
    log_x: bool,
) -> Result<()> {
    register_font();
    let (w, h) = (560 * panels.len().max(1) as u32, 420u32);
    let tmp = path.with_extension(format!("tmp{}.png", std::process::id()));
    {
        let root = BitMapBackend::new(&tmp, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        let areas = root.split_evenly((1, panels.len().max(1)));
        let colors = [
            RGBColor(31, 119, 180),
            RGBColor(214, 39, 40),
            RGBColor(44, 160, 44),
            RGBColor(148, 103, 189),
            RGBColor(255, 127, 14),
        ];
        for (area, (title, y_label, series)) in areas.iter().zip(panels) {
            let pts = series.iter().flat_map(|s| s.points.iter());
            let (mut x0, mut x1, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
            for &(x, y) in pts {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y1 = y1.max(y);
            }
            if !x0.is_finite() {
                continue;
            }
            let x0 = if log_x { x0.max(1e-9) } else { x0 };
            let x1 = if x1 > x0 { x1 } else { x0 + 1.0 };
            let y1 = if y1 > 0.0 { y1 * 1.08 } else { 1.0 };
            let mut chart = ChartBuilder::on(area);
            chart
                .caption(title, ("sans-serif", 20))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60);
            macro_rules! draw {
                ($chart:expr) => {{
                    let mut c = $chart;
                    c.configure_mesh()
                        .x_labels(8)
                        .x_label_formatter(&|x| format!("{}", *x as f64))
                        .x_desc(x_label)
                        .y_desc(y_label.as_str())
                        .label_style(("sans-serif", 13))
                        .draw()?;
                    for (i, s) in series.iter().enumerate() {
                        let col = colors[i % colors.len()];
                        c.draw_series(LineSeries::new(
                            s.points.iter().copied(),
                            col.stroke_width(2),
                        ))?
                        .label(s.name.as_str())
                        .legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 18, y)], col.stroke_width(2))
                        });
                        c.draw_series(s.points.iter().map(|&p| Circle::new(p, 3, col.filled())))?;
                    }
                    c.configure_series_labels()
                        .background_style(WHITE.mix(0.8))
                        .border_style(BLACK)
                        .label_font(("sans-serif", 13))
                        .draw()?;
                }};
            }
            if log_x {
                draw!(chart.build_cartesian_2d((x0..x1).log_scale(), 0.0..y1)?);
            } else {
                draw!(chart.build_cartesian_2d(x0..x1, 0.0..y1)?);
            }
        }
        root.present().context("writing the plot")?;
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        anyhow::anyhow!("{}: {e}", path.display())
    })
}

/// The paper's Fig. 7 from component curves: `csv_path` (one row per part and component
/// count: RL/RA residual RMS and mesh error) and `png_path` (three panels, log x axis).
pub fn component_curves_files(
    csv_path: &Path,
    png_path: &Path,
    curves: &[panoman_model::train::CurvePoint],
) -> Result<()> {
    let mut csv = String::from("part,k,rl_rms,ra_rms_rad,mesh_mean_mm,mesh_max_mm\n");
    for p in curves {
        csv.push_str(&format!(
            "{},{},{:.6e},{:.6e},{:.4},{:.4}\n",
            p.part, p.k, p.rl_rms, p.ra_rms, p.mesh_mean_mm, p.mesh_max_mm
        ));
    }
    crate::util::write_atomic(csv_path, &csv)?;
    let series = |f: &dyn Fn(&panoman_model::train::CurvePoint) -> f64| -> Vec<Series> {
        ["body", "face", "hands"]
            .iter()
            .map(|part| Series {
                name: part.to_string(),
                points: curves
                    .iter()
                    .filter(|p| p.part == *part)
                    .map(|p| (p.k as f64, f(p)))
                    .collect(),
            })
            .filter(|s| !s.points.is_empty())
            .collect()
    };
    line_panels(
        png_path,
        &[
            (
                "RL approximation error".into(),
                "RMS of RL residual".into(),
                series(&|p| p.rl_rms),
            ),
            (
                "RA approximation error".into(),
                "RMS of RA residual (rad)".into(),
                series(&|p| p.ra_rms),
            ),
            (
                "Mesh error".into(),
                "mean per-vertex error (mm)".into(),
                series(&|p| p.mesh_mean_mm),
            ),
        ],
        "number of components (per block)",
        true,
    )
}
