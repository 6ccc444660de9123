//! The error-against-time plot (plotters, drawn into memory, encoded as PNG).

use anyhow::Context;
use plotters::prelude::*;

/// One method's curve: (seconds, error) points.
pub struct Curve {
    pub label: String,
    pub points: Vec<(f64, f64)>,
}

/// Registers the embedded font once (plotters draws text with ab_glyph; no system fonts needed).
fn font() -> anyhow::Result<()> {
    static ONCE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *ONCE.get_or_init(|| {
        plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            epaint_default_fonts::UBUNTU_LIGHT,
        )
        .is_ok()
    });
    anyhow::ensure!(ok, "the embedded plot font did not load");
    Ok(())
}

/// Tick values of a log axis over `[lo, hi]`: 1, 2 and 5 times the powers of ten inside it,
/// so that a range within one decade (a light-map curve: 1.3 to 4.7 s) is labelled too.
fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return Vec::new();
    }
    let mut out = Vec::new();
    let mut decade = 10f64.powi(lo.log10().floor() as i32);
    while decade <= hi && out.len() < 64 {
        for m in [1.0, 2.0, 5.0] {
            let v = decade * m;
            if v >= lo && v <= hi {
                out.push(v);
            }
        }
        decade *= 10.0;
    }
    out
}

/// Plots error (log) against seconds (log); returns PNG bytes.
pub fn plot_convergence(curves: &[Curve], title: &str) -> anyhow::Result<Vec<u8>> {
    font()?;
    let (w, h) = (1000u32, 640u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).context("plot")?;
        let pts = curves
            .iter()
            .flat_map(|c| c.points.iter())
            .filter(|(t, e)| *t > 0.0 && *e > 0.0 && e.is_finite());
        let (mut t0, mut t1, mut e0, mut e1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
        for &(t, e) in pts {
            t0 = t0.min(t);
            t1 = t1.max(t);
            e0 = e0.min(e);
            e1 = e1.max(e);
        }
        if !t0.is_finite() {
            (t0, t1, e0, e1) = (1e-3, 1.0, 1e-4, 1.0);
        }
        let (t0, t1) = (t0 * 0.8, (t1 * 1.25).max(t0 * 2.0));
        let (e0, e1) = ((e0 * 0.5).min(5e-3), (e1 * 2.0).max(e0 * 4.0));
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(
                (t0..t1).log_scale().with_key_points(ticks(t0, t1)),
                (e0..e1).log_scale().with_key_points(ticks(e0, e1)),
            )
            .context("plot axes")?;
        chart
            .configure_mesh()
            .x_desc("wall time (s), form factors included")
            .y_desc("relative error (each curve says which)")
            .y_label_formatter(&|v| format!("{:.2} %", v * 100.0))
            .x_label_formatter(&|v| {
                let s = format!("{v:.3}");
                s.trim_end_matches('0').trim_end_matches('.').to_string()
            })
            .draw()
            .context("plot mesh")?;
        // The 1 % line.
        chart
            .draw_series(LineSeries::new(
                [(t0, 0.01), (t1, 0.01)],
                BLACK.mix(0.4).stroke_width(1),
            ))
            .context("plot")?
            .label("1 %")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.mix(0.4)));
        for (k, c) in curves.iter().enumerate() {
            let color = Palette99::pick(k).to_rgba();
            let points: Vec<(f64, f64)> = c
                .points
                .iter()
                .copied()
                .filter(|(t, e)| *t > 0.0 && *e > 0.0 && e.is_finite())
                .collect();
            chart
                .draw_series(LineSeries::new(points, color.stroke_width(2)))
                .context("plot")?
                .label(c.label.clone())
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .context("plot legend")?;
        root.present().context("plot")?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).context("plot buffer")?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)?;
    Ok(bytes.into_inner())
}
