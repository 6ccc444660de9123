//! Colorimetry against the tables exported from colour-science (tests/data/, written by
//! tools/make_colour_fixtures.py): matrices, colour-matching functions, ColorChecker and Cornell
//! spectra, blackbody chromaticity, Bradford adaptation, ΔE2000, out-of-gamut handling.
#![expect(
    clippy::needless_range_loop,
    reason = "matrix and channel indices read more plainly than iterator chains"
)]

use radiant_color::cie::{
    self, GamutMapping, Spectrum, bradford, delta_e_2000, map_to_gamut, mul, reflectance_to_xyz,
    xy, xyz_to_lab, xyz_to_srgb_linear,
};

fn table(text: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let mut lines = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty());
    let header = lines
        .next()
        .expect("header")
        .split(',')
        .map(str::to_string)
        .collect();
    (
        header,
        lines
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect(),
    )
}

fn num(s: &str) -> f64 {
    s.trim().parse().expect("number")
}

fn refs() -> serde_json::Value {
    serde_json::from_str(include_str!("data/srgb_and_cornell_colour_refs.json")).expect("json")
}

#[test]
fn srgb_matrices_follow_from_primaries_and_white() {
    let r = refs();
    let (to_xyz, to_rgb) = cie::srgb_matrices();
    for i in 0..3 {
        for j in 0..3 {
            let want = r["matrix_RGB_to_XYZ_from_primaries"][i][j]
                .as_f64()
                .expect("f64");
            assert!(
                (to_xyz[i][j] - want).abs() < 1e-12,
                "RGB->XYZ [{i}][{j}] {} vs {want}",
                to_xyz[i][j]
            );
            let want = r["matrix_XYZ_to_RGB_from_primaries"][i][j]
                .as_f64()
                .expect("f64");
            assert!(
                (to_rgb[i][j] - want).abs() < 1e-12,
                "XYZ->RGB [{i}][{j}] {} vs {want}",
                to_rgb[i][j]
            );
        }
    }
    // Round trip.
    for rgb in [[0.2, 0.5, 0.9], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]] {
        let back = mul(to_rgb, mul(to_xyz, rgb));
        for c in 0..3 {
            assert!((back[c] - rgb[c]).abs() < 1e-12);
        }
    }
}

#[test]
fn srgb_transfer_matches_the_test_vectors() {
    let r = refs();
    for v in r["encode_test_vectors"].as_array().expect("array") {
        let (l, e) = (v[0].as_f64().expect("f64"), v[1].as_f64().expect("f64"));
        assert!(
            (radiant_color::linear_to_srgb(l) - e).abs() < 1e-9,
            "encode {l}"
        );
    }
    for v in r["decode_test_vectors"].as_array().expect("array") {
        let (e, l) = (v[0].as_f64().expect("f64"), v[1].as_f64().expect("f64"));
        assert!(
            (radiant_color::srgb_to_linear(e) - l).abs() < 1e-9,
            "decode {e}"
        );
    }
}

#[test]
fn colour_matching_functions() {
    let xyz = cie::cmf_xyz();
    assert_eq!(xyz.len(), 471);
    assert_eq!((xyz[0].0, xyz[470].0), (360.0, 830.0));
    // Equal-energy white sits at x = y = 1/3: the three functions have equal areas.
    let e = reflectance_to_xyz(&Spectrum::constant(1.0), &Spectrum::constant(1.0)).1;
    let c = xy(e);
    assert!(
        (c[0] - 1.0 / 3.0).abs() < 1e-4 && (c[1] - 1.0 / 3.0).abs() < 1e-4,
        "{c:?}"
    );
    // The lecture's example: at 500 nm a match needs a negative amount of red.
    let rgb = cie::cmf_rgb();
    let at500 = rgb.iter().find(|r| r.0 == 500.0).expect("500 nm").1;
    assert!(
        at500[0] < 0.0 && at500[1] > 0.0 && at500[2] > 0.0,
        "{at500:?}"
    );
    // ... and the monochromatic 500 nm light is outside the sRGB gamut, reported as such.
    let mono = xyz.iter().find(|r| r.0 == 500.0).expect("500 nm").1;
    let (lin, out) = xyz_to_srgb_linear(mono);
    assert!(out && lin[0] < 0.0, "{lin:?}");
    // The spectral locus is horseshoe-shaped: its ends are at the red and violet corners.
    let locus = cie::spectral_locus();
    assert!(
        locus
            .iter()
            .all(|(_, c)| c[0] >= 0.0 && c[1] >= 0.0 && c[0] + c[1] <= 1.0 + 1e-9)
    );
}

#[test]
fn colorchecker_under_d65_within_delta_e_half() {
    let (header, rows) = table(include_str!(
        "data/colorchecker_babelcolor_average_reflectance.csv"
    ));
    let (_, want) = table(include_str!(
        "data/colorchecker_babelcolor_average_D65_XYZ_sRGB.csv"
    ));
    let wl: Vec<f64> = rows.iter().map(|r| num(&r[0])).collect();
    let mut worst = 0.0f64;
    for (p, name) in header.iter().enumerate().skip(1) {
        let values: Vec<f64> = rows.iter().map(|r| num(&r[p])).collect();
        let s = Spectrum::new(wl.clone(), values).expect("spectrum");
        let (got, white) = reflectance_to_xyz(&s, cie::d65());
        let w = want
            .iter()
            .find(|r| r[0] == *name)
            .unwrap_or_else(|| panic!("{name} in reference"));
        let ref_xyz = [num(&w[1]), num(&w[2]), num(&w[3])];
        let de = delta_e_2000(xyz_to_lab(got, white), xyz_to_lab(ref_xyz, white));
        worst = worst.max(de);
        assert!(
            de <= 0.5,
            "{name}: ΔE2000 {de:.3} (ours {got:?}, reference {ref_xyz:?})"
        );
        let (lin, _) = xyz_to_srgb_linear(got);
        for c in 0..3 {
            assert!(
                (lin[c] - num(&w[4 + c])).abs() < 5e-3,
                "{name} linear sRGB {lin:?}"
            );
        }
    }
    println!("ColorChecker under D65: worst ΔE2000 {worst:.3}");
}

#[test]
fn cornell_spectra_give_the_known_rgb_sets() {
    let r = refs();
    let (header, rows) = table(include_str!("data/cornell_spectra_reflectance.csv"));
    let wl: Vec<f64> = rows.iter().map(|r| num(&r[0])).collect();
    for (p, name) in header.iter().enumerate().skip(1) {
        let s =
            Spectrum::new(wl.clone(), rows.iter().map(|r| num(&r[p])).collect()).expect("spectrum");
        for (illum, spd) in [("E", Spectrum::constant(1.0)), ("D65", cie::d65().clone())] {
            let key = format!("{name}_under_{illum}");
            let want = &r["cornell_reflectances_400_700_4nm"][&key];
            let (xyz, white) = reflectance_to_xyz(&s, &spd);
            for c in 0..3 {
                let w = want["XYZ"][c].as_f64().expect("XYZ");
                assert!(
                    (xyz[c] - w).abs() < 2e-3 * w.max(0.1),
                    "{key} XYZ[{c}]: {} vs {w}",
                    xyz[c]
                );
                let ww = want["white_XYZ"][c].as_f64().expect("white");
                assert!(
                    (white[c] - ww).abs() < 2e-3,
                    "{key} white[{c}]: {} vs {ww}",
                    white[c]
                );
            }
            let (lin, _) = xyz_to_srgb_linear(xyz);
            for c in 0..3 {
                let w = want["linear_sRGB_no_adaptation"][c].as_f64().expect("rgb");
                assert!(
                    (lin[c] - w).abs() < 3e-3,
                    "{key} linear sRGB[{c}]: {} vs {w}",
                    lin[c]
                );
            }
        }
    }
}

#[test]
fn blackbody_at_2856_kelvin_is_illuminant_a() {
    let (_, rows) = table(include_str!("data/illuminant_a_xy.csv"));
    let want = [num(&rows[0][0]), num(&rows[0][1])];
    let s = Spectrum::blackbody(2856.0);
    let got = xy(reflectance_to_xyz(&Spectrum::constant(1.0), &s).1);
    assert!(
        (got[0] - want[0]).abs() < 5e-4 && (got[1] - want[1]).abs() < 5e-4,
        "{got:?} vs {want:?}"
    );
    // Wien: the peak moves to shorter wavelengths as the temperature rises.
    let peak = |t: f64| {
        let s = Spectrum::blackbody(t);
        (360..=830)
            .map(f64::from)
            .max_by(|a, b| s.at(*a).total_cmp(&s.at(*b)))
            .expect("peak")
    };
    assert!(peak(6500.0) < peak(4000.0));
}

#[test]
fn bradford_maps_white_to_white() {
    let d65 = reflectance_to_xyz(&Spectrum::constant(1.0), cie::d65()).1;
    let a = reflectance_to_xyz(&Spectrum::constant(1.0), &Spectrum::blackbody(2856.0)).1;
    let m = bradford(a, d65).expect("matrix");
    let mapped = mul(&m, a);
    for c in 0..3 {
        assert!((mapped[c] - d65[c]).abs() < 1e-12);
    }
    let id = bradford(d65, d65).expect("identity");
    for i in 0..3 {
        for j in 0..3 {
            assert!((id[i][j] - f64::from(u8::from(i == j))).abs() < 1e-12);
        }
    }
}

#[test]
fn delta_e_2000_matches_colour_science() {
    let (_, rows) = table(include_str!("data/delta_e_2000_pairs.csv"));
    for r in rows {
        let v: Vec<f64> = r.iter().map(|s| num(s)).collect();
        let de = delta_e_2000([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
        assert!((de - v[6]).abs() < 1e-6, "{v:?}: {de}");
    }
}

#[test]
fn out_of_gamut_colours_are_mapped_by_a_stated_method() {
    let rgb = [-0.2, 0.8, 0.3];
    let clip = map_to_gamut(rgb, GamutMapping::Clip);
    assert_eq!(clip, [0.0, 0.8, 0.3]);
    let d = map_to_gamut(rgb, GamutMapping::Desaturate);
    assert!(d.iter().all(|c| (0.0..=1.0).contains(c)));
    // Desaturation keeps the luminance and the order of the channels.
    assert!((radiant_color::luminance(d) - radiant_color::luminance(rgb)).abs() < 1e-12);
    assert!(d[1] > d[2] && d[2] > d[0]);
    // In gamut: untouched.
    assert_eq!(
        map_to_gamut([0.1, 0.2, 0.3], GamutMapping::Desaturate),
        [0.1, 0.2, 0.3]
    );
}

/// The Planckian locus against colour-science 0.4.7: `sd_blackbody(T, 360–830 nm at 1 nm)`,
/// `sd_to_XYZ(…, CIE 1931 2°, method="Integration")`, `XYZ_to_xy` (computed on 2026-11-22).
#[test]
fn blackbody_chromaticity_matches_colour_science() {
    let reference = [
        (1500.0, [0.585_720_99, 0.393_119_69]),
        (2000.0, [0.526_680_99, 0.413_296_46]),
        (4000.0, [0.380_442_36, 0.376_748_59]),
        (6500.0, [0.313_527_51, 0.323_629_89]),
        (10000.0, [0.280_634_46, 0.288_288_89]),
    ];
    for (t, xy) in reference {
        let (c, rgb) = cie::blackbody_color(t).expect("a colour");
        assert!(
            (c[0] - xy[0]).abs() < 2e-4 && (c[1] - xy[1]).abs() < 2e-4,
            "{t} K: {c:?} vs {xy:?}"
        );
        let peak = rgb.iter().copied().fold(0.0, f64::max);
        assert!((peak - 1.0).abs() < 1e-12 && rgb.iter().all(|&v| v >= 0.0));
    }
    // Warm is red-heavy, cool is blue-heavy.
    let (_, warm) = cie::blackbody_color(2000.0).expect("colour");
    let (_, cool) = cie::blackbody_color(10000.0).expect("colour");
    assert!(warm[0] > warm[1] && warm[1] > warm[2]);
    assert!(cool[2] > cool[0]);
    for bad in [0.0, -5.0, f64::NAN, f64::INFINITY] {
        assert!(cie::blackbody_color(bad).is_none());
    }
}
