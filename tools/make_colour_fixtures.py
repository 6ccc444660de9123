#!/usr/bin/env python3
"""Writes the colour tables radiant_color embeds, and its test fixtures.

Sources: the CIE tables exported from colour-science beside the project (../shared/refs/colour/),
and colour-science itself (pip install colour-science) for the D65 spectral power distribution.

  crates/radiant_color/data/cie1931_xyz_cmf_1nm.csv      CIE 1931 2° x̄ȳz̄, 360–830 nm, 1 nm
  crates/radiant_color/data/cie1931_rgb_cmf_5nm.csv      CIE 1931 r̄ḡb̄ derived from x̄ȳz̄ (the
                                                         tabulated file has 2 transposed rows)
  crates/radiant_color/data/cie_d65_5nm.csv              CIE standard illuminant D65, 300–830 nm, 5 nm
  crates/radiant_color/tests/data/*                      ColorChecker and Cornell references
"""
import shutil
from pathlib import Path

import colour

root = Path(__file__).resolve().parent.parent
refs = root.parent / "shared/refs/colour"
data = root / "crates/radiant_color/data"
tests = root / "crates/radiant_color/tests/data"
data.mkdir(parents=True, exist_ok=True)
tests.mkdir(parents=True, exist_ok=True)

shutil.copy(refs / "cie1931_xyz_cmf_1nm_360_830.csv", data / "cie1931_xyz_cmf_1nm.csv")
shutil.copy(refs / "cie1931_rgb_cmf_derived_from_xyz_5nm.csv", data / "cie1931_rgb_cmf_5nm.csv")
d65 = colour.SDS_ILLUMINANTS["D65"]
with open(data / "cie_d65_5nm.csv", "w") as f:
    f.write(f"# CIE standard illuminant D65, relative SPD (colour-science {colour.__version__})\n")
    f.write("wavelength_nm,value\n")
    for w, v in zip(d65.wavelengths, d65.values):
        f.write(f"{int(w)},{v:.6f}\n")
for name in [
    "colorchecker_babelcolor_average_reflectance.csv",
    "colorchecker_babelcolor_average_D65_XYZ_sRGB.csv",
    "srgb_and_cornell_colour_refs.json",
]:
    shutil.copy(refs / name, tests / name)
shutil.copy(root.parent / "shared/refs/cornell/cornell_spectra_reflectance.csv", tests / "cornell_spectra_reflectance.csv")
a = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["A"]
with open(tests / "illuminant_a_xy.csv", "w") as f:
    f.write("# CIE illuminant A (Planckian, 2856 K) chromaticity, colour-science\nx,y\n")
    f.write(f"{a[0]:.6f},{a[1]:.6f}\n")
print("wrote", data, tests)
