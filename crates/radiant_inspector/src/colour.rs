//! Colour widgets: linear RGB, sRGB hex and HDR intensity editors, the CIE 1931 xy diagram,
//! and a colour-temperature picker.

use egui::{Align2, Color32, FontId, Pos2, Rect, Sense, Shape, Stroke, Ui, Vec2};
use radiant_color::cie;

use crate::inspect::drag;

/// The sRGB hex code (`#rrggbb`) of a linear colour, channels clamped to [0, 1].
pub fn to_hex(linear: [f64; 3]) -> String {
    let [r, g, b] = linear.map(radiant_color::linear_to_srgb8);
    format!("#{r:02x}{g:02x}{b:02x}")
}

/// Parses `#rrggbb` or `rrggbb` into a linear colour; `None` for anything else.
pub fn from_hex(text: &str) -> Option<[f64; 3]> {
    let t = text.trim().trim_start_matches('#');
    if t.len() != 6 || !t.is_ascii() {
        return None;
    }
    let byte = |i: usize| u8::from_str_radix(&t[i..i + 2], 16).ok();
    let (r, g, b) = (byte(0)?, byte(2)?, byte(4)?);
    Some([r, g, b].map(|v| radiant_color::srgb_to_linear(f64::from(v) / 255.0)))
}

/// xy chromaticity of a linear sRGB colour (the D65 white for black).
pub fn chromaticity(linear: [f64; 3]) -> [f64; 2] {
    cie::xy(cie::mul(&cie::srgb_matrices().0, linear))
}

/// CIE Y of a linear sRGB colour (through the same matrix as [`chromaticity`]).
pub fn luminance_y(linear: [f64; 3]) -> f64 {
    cie::mul(&cie::srgb_matrices().0, linear)[1]
}

/// The linear sRGB colour of chromaticity `xy` at luminance `y_lum`, and whether it was outside
/// the sRGB gamut (then it is desaturated into it). `None` for a chromaticity with y ≤ 0.
pub fn from_chromaticity(xy: [f64; 2], y_lum: f64) -> Option<([f64; 3], bool)> {
    if !(xy[1] > 1e-6 && xy[0] >= 0.0 && xy[0] + xy[1] <= 1.0) {
        return None;
    }
    let xyz = [
        xy[0] / xy[1] * y_lum,
        y_lum,
        (1.0 - xy[0] - xy[1]) / xy[1] * y_lum,
    ];
    let (rgb, out) = cie::xyz_to_srgb_linear(xyz);
    let negative = rgb.iter().any(|&c| c < 0.0);
    let rgb = if negative {
        cie::map_to_gamut(rgb, cie::GamutMapping::Desaturate)
    } else {
        rgb
    };
    Some((rgb, negative || (out && rgb.iter().any(|&c| c < 0.0))))
}

/// Whether `p` lies inside the sRGB gamut triangle (edges included, to 1e-9).
pub fn in_srgb_gamut(p: [f64; 2]) -> bool {
    const EPS: f64 = 1e-9;
    let [a, b, c] = cie::SRGB_PRIMARIES_XY;
    let side =
        |u: [f64; 2], v: [f64; 2]| (v[0] - u[0]) * (p[1] - u[1]) - (v[1] - u[1]) * (p[0] - u[0]);
    let (s1, s2, s3) = (side(a, b), side(b, c), side(c, a));
    (s1 >= -EPS && s2 >= -EPS && s3 >= -EPS) || (s1 <= EPS && s2 <= EPS && s3 <= EPS)
}

fn color32(linear: [f64; 3]) -> Color32 {
    let [r, g, b] = linear.map(radiant_color::linear_to_srgb8);
    Color32::from_rgb(r, g, b)
}

/// A colour edited as linear RGB, sRGB hex and a picker. Returns whether it changed.
/// `hex` is the text buffer of the hex field (kept across frames by the caller).
pub fn rgb_editor(ui: &mut Ui, id: &str, rgb: &mut [f64; 3], max: f64, hex: &mut String) -> bool {
    let mut changed = false;
    ui.horizontal(|ui| {
        ui.label("linear");
        for (c, name) in rgb.iter_mut().zip(["R", "G", "B"]) {
            let (_, edited) = drag(ui, c, |d| {
                d.range(0.0..=max)
                    .speed(0.002)
                    .max_decimals(4)
                    .prefix(format!("{name} "))
            });
            changed |= edited;
        }
        let mut f = rgb.map(|v| v.clamp(0.0, 1.0) as f32);
        if ui.color_edit_button_rgb(&mut f).changed() {
            *rgb = f.map(|v| f64::from(v).min(max));
            changed = true;
        }
    });
    ui.horizontal(|ui| {
        let label = ui.label("sRGB");
        let current = to_hex(*rgb);
        if changed || hex.is_empty() {
            *hex = current.clone();
        }
        let edit = ui
            .add(
                egui::TextEdit::singleline(hex)
                    .id_salt(id)
                    .desired_width(80.0)
                    .char_limit(7),
            )
            .labelled_by(label.id);
        if edit.changed()
            && let Some(c) = from_hex(hex)
        {
            *rgb = c.map(|v| v.min(max));
            changed = true;
        }
        if edit.lost_focus() {
            *hex = to_hex(*rgb);
        }
        if from_hex(hex).is_none() {
            ui.colored_label(Color32::from_rgb(230, 90, 70), "not #rrggbb");
        }
    });
    changed
}

/// An emission edited as a colour (largest channel 1) times an HDR intensity. Returns whether
/// it changed.
pub fn hdr_editor(ui: &mut Ui, id: &str, emission: &mut [f64; 3], hex: &mut String) -> bool {
    let peak = emission.iter().copied().fold(0.0, f64::max);
    let mut colour = if peak > 0.0 {
        emission.map(|v| v / peak)
    } else {
        [1.0; 3]
    };
    let mut intensity = peak;
    let mut changed = rgb_editor(ui, id, &mut colour, 1.0, hex);
    ui.horizontal(|ui| {
        let label = ui.label("HDR intensity");
        let speed = (intensity * 0.01).max(0.01);
        let (response, edited) = drag(ui, &mut intensity, |d| {
            d.range(0.0..=1e6).speed(speed).max_decimals(3)
        });
        response.labelled_by(label.id);
        changed |= edited;
    });
    if changed && intensity <= 0.0 && colour != [1.0; 3] {
        // A colour picked for a surface that does not emit yet: make it glow at 1.
        intensity = 1.0;
    }
    let new = colour.map(|c| c * intensity);
    if changed && new != *emission && new.iter().all(|v| v.is_finite()) {
        *emission = new;
        true
    } else {
        false
    }
}

/// Draws the CIE 1931 xy diagram: the spectral locus with wavelength marks, the sRGB gamut
/// triangle, the white point and `points` (label, xy, colour). A point outside the gamut gets
/// a red ring. Returns the xy the user clicked or dragged to, if any.
pub fn chromaticity_diagram(
    ui: &mut Ui,
    size: f32,
    points: &[(&str, [f64; 2], [f64; 3])],
) -> Option<[f64; 2]> {
    let (response, painter) = ui.allocate_painter(Vec2::splat(size), Sense::click_and_drag());
    let rect = response.rect;
    let frame = Rect::from_min_max(
        rect.min + Vec2::new(24.0, 6.0),
        rect.max - Vec2::new(6.0, 20.0),
    );
    // x in [0, 0.8], y in [0, 0.9].
    let to_screen = |p: [f64; 2]| {
        Pos2::new(
            frame.left() + (p[0] / 0.8) as f32 * frame.width(),
            frame.bottom() - (p[1] / 0.9) as f32 * frame.height(),
        )
    };
    let from_screen = |q: Pos2| {
        [
            f64::from((q.x - frame.left()) / frame.width()) * 0.8,
            f64::from((frame.bottom() - q.y) / frame.height()) * 0.9,
        ]
    };
    let visuals = ui.visuals();
    painter.rect_filled(rect, 2.0, visuals.extreme_bg_color);
    let axis = Stroke::new(1.0, visuals.weak_text_color());
    let text = visuals.text_color();
    for i in 0..=8 {
        let x = f64::from(i) * 0.1;
        let a = to_screen([x, 0.0]);
        painter.line_segment([a, a + Vec2::new(0.0, 3.0)], axis);
        if i % 2 == 0 {
            painter.text(
                a + Vec2::new(0.0, 4.0),
                Align2::CENTER_TOP,
                format!("{x:.1}"),
                FontId::proportional(9.0),
                text,
            );
        }
    }
    for i in 0..=9 {
        let y = f64::from(i) * 0.1;
        let a = to_screen([0.0, y]);
        painter.line_segment([a, a - Vec2::new(3.0, 0.0)], axis);
        if i % 2 == 0 {
            painter.text(
                a - Vec2::new(4.0, 0.0),
                Align2::RIGHT_CENTER,
                format!("{y:.1}"),
                FontId::proportional(9.0),
                text,
            );
        }
    }
    painter.line_segment([to_screen([0.0, 0.0]), to_screen([0.8, 0.0])], axis);
    painter.line_segment([to_screen([0.0, 0.0]), to_screen([0.0, 0.9])], axis);

    // Spectral locus 380–700 nm (beyond, the points pile up), closed by the line of purples.
    let locus: Vec<(f64, [f64; 2])> = cie::spectral_locus()
        .into_iter()
        .filter(|(w, _)| (380.0..=700.0).contains(w))
        .collect();
    let outline: Vec<Pos2> = locus.iter().map(|(_, p)| to_screen(*p)).collect();
    painter.add(Shape::closed_line(outline, Stroke::new(1.5, text)));
    for (w, p) in &locus {
        let w = *w as i32;
        if [460, 480, 500, 520, 540, 560, 580, 600, 620].contains(&w) {
            let q = to_screen(*p);
            painter.circle_filled(q, 1.5, text);
            let right = p[0] > 0.3;
            painter.text(
                q + Vec2::new(if right { 4.0 } else { -4.0 }, 0.0),
                if right {
                    Align2::LEFT_CENTER
                } else {
                    Align2::RIGHT_CENTER
                },
                format!("{w}"),
                FontId::proportional(8.0),
                visuals.weak_text_color(),
            );
        }
    }
    // The lecture's example: 500 nm lies outside every mix of positive primaries; matching it
    // needs a negative amount of red (CIE 1931 RGB r̄ < 0).
    if let Some((_, p)) = locus.iter().find(|(w, _)| *w == 500.0) {
        let q = to_screen(*p);
        painter.circle_stroke(q, 5.0, Stroke::new(1.5, Color32::from_rgb(230, 60, 50)));
        if let Some((_, rgb)) = cie::cmf_rgb().iter().find(|(w, _)| *w == 500.0) {
            painter.text(
                q + Vec2::new(8.0, 2.0),
                Align2::LEFT_TOP,
                format!("500 nm: red {:+.3}", rgb[0]),
                FontId::proportional(9.0),
                Color32::from_rgb(230, 90, 70),
            );
        }
    }
    // sRGB gamut and white.
    let tri: Vec<Pos2> = cie::SRGB_PRIMARIES_XY
        .iter()
        .map(|p| to_screen(*p))
        .collect();
    painter.add(Shape::closed_line(
        tri,
        Stroke::new(1.0, Color32::from_rgb(120, 170, 240)),
    ));
    painter.text(
        to_screen([0.64, 0.33]) + Vec2::new(4.0, 0.0),
        Align2::LEFT_CENTER,
        "sRGB",
        FontId::proportional(9.0),
        Color32::from_rgb(120, 170, 240),
    );
    painter.circle_stroke(to_screen(cie::SRGB_WHITE_XY), 2.0, Stroke::new(1.0, text));
    for (label, p, rgb) in points {
        let q = to_screen(*p);
        painter.circle_filled(q, 4.5, color32(*rgb));
        painter.circle_stroke(q, 4.5, Stroke::new(1.0, text));
        if !in_srgb_gamut(*p) {
            painter.circle_stroke(q, 7.5, Stroke::new(2.0, Color32::from_rgb(230, 60, 50)));
        }
        painter.text(
            q + Vec2::new(8.0, -8.0),
            Align2::LEFT_BOTTOM,
            *label,
            FontId::proportional(10.0),
            text,
        );
    }
    // A click, or a drag that moved: holding the button still writes nothing.
    let picked = if response.clicked() || response.drag_delta() != Vec2::ZERO {
        response.interact_pointer_pos().map(from_screen)
    } else {
        None
    };
    picked.filter(|p| p[1] > 0.0 && p[0] >= 0.0 && p[0] + p[1] <= 1.0)
}

/// A colour-temperature picker: a Kelvin drag value and a swatch. Returns the linear colour
/// (largest channel 1) when the user changed the temperature.
pub fn kelvin_picker(ui: &mut Ui, kelvin: &mut f64) -> Option<[f64; 3]> {
    let mut out = None;
    ui.horizontal(|ui| {
        let label = ui.label("temperature");
        let (response, changed) = drag(ui, kelvin, |d| {
            d.range(1000.0..=40000.0).speed(20.0).suffix(" K")
        });
        response.labelled_by(label.id);
        if let Some((_, rgb)) = cie::blackbody_color(*kelvin) {
            let (r, _) = ui.allocate_exact_size(Vec2::new(28.0, 14.0), Sense::hover());
            ui.painter().rect_filled(r, 2.0, color32(rgb));
            if changed {
                out = Some(rgb);
            }
        }
        for (name, k) in [
            ("candle", 1900.0),
            ("tungsten", 2856.0),
            ("D65-ish", 6504.0),
        ] {
            if ui.small_button(name).clicked() {
                *kelvin = k;
                out = cie::blackbody_color(k).map(|(_, rgb)| rgb);
            }
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_round_trips_and_rejects_garbage() {
        for hex in ["#000000", "#ffffff", "#ba3b1f", "#7f7f7f"] {
            let c = from_hex(hex).expect("valid");
            assert_eq!(to_hex(c), hex);
        }
        assert_eq!(from_hex("ba3b1f"), from_hex("#ba3b1f"));
        for bad in ["", "#12345", "#1234567", "#gg0000", "#ééé"] {
            assert!(from_hex(bad).is_none(), "{bad}");
        }
    }

    #[test]
    fn chromaticity_round_trip_and_gamut() {
        let c = [0.2, 0.5, 0.1];
        let xy = chromaticity(c);
        let y = luminance_y(c);
        let (back, out) = from_chromaticity(xy, y).expect("valid");
        assert!(!out);
        for k in 0..3 {
            assert!((back[k] - c[k]).abs() < 1e-9);
        }
        assert!(in_srgb_gamut(cie::SRGB_WHITE_XY));
        // 520 nm green lies far outside sRGB; it is desaturated into it.
        let green = [0.0743, 0.8338];
        assert!(!in_srgb_gamut(green));
        let (rgb, out) = from_chromaticity(green, 0.5).expect("valid");
        assert!(out && rgb.iter().all(|v| (0.0..=1.0).contains(v)));
        assert!(from_chromaticity([0.3, 0.0], 1.0).is_none());
        assert!(from_chromaticity([f64::NAN, 0.3], 1.0).is_none());
    }
}
