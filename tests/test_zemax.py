"""Zemax .zmx import: the two patent lenses, encodings, glass fallbacks and one-line
errors naming the file and the field."""

import math
import warnings

import pytest

from lensim.errors import InputError
from lensim.optics.lens_file import GlassSubstitutionWarning, lens_to_dict, load_lens
from lensim.optics.materials import CatalogGlass, ConstantIndex, ModelGlass
from lensim.optics.paraxial import paraxial_data
from lensim.optics.zemax import read_zmx

DOUBLE_GAUSS = "US00583336-2-scaled.zmx"
ASPHERIC = "US08427765-1.zmx"
F_D_C_UM = [0.4861327, 0.5875618, 0.6562725]


@pytest.fixture(scope="module")
def gauss(reference_lenses):
    return read_zmx(reference_lenses / DOUBLE_GAUSS)


@pytest.fixture(scope="module")
def aspheric(reference_lenses):
    return read_zmx(reference_lenses / ASPHERIC)


def source_text(reference_lenses, name: str) -> str:
    with open(reference_lenses / name, encoding="ascii", newline="") as fh:
        return fh.read()


def variant(tmp_path, reference_lenses, name, old, new, count=1):
    """A copy of a reference lens with `old` replaced by `new` (CRLF kept)."""
    text = source_text(reference_lenses, name)
    assert text.count(old) >= count, old
    p = tmp_path / name
    p.write_bytes(text.replace(old, new, count).encode("ascii"))
    return p


def test_double_gauss_patent_lens(gauss):
    lens = gauss
    assert lens.name == "Original Double Gauss"
    assert lens.num_surfaces == 12 and lens.stop_index == 6
    assert (lens.aperture_type, lens.aperture_value) == ("fno", 4.5)
    assert lens.field_type == "angle" and lens.fields == [0.0, 17.0, 24.0]
    assert lens.wavelengths_um == F_D_C_UM and lens.primary == 1
    assert math.isinf(lens.object_distance)
    assert lens.surfaces[1].material == CatalogGlass("N-BAK1", "Schott", None)
    assert lens.surfaces[4].material == CatalogGlass("N-BALF4", "Schott", None)
    # FLAP: a floating aperture clips at the semi-diameter; a plain DIAM only draws
    assert (lens.surfaces[1].clear_radius, lens.surfaces[1].semi_diameter) == (6.3, 6.3)
    assert lens.surfaces[6].clear_radius is None and lens.surfaces[6].semi_diameter == pytest.approx(4.215000499256)
    assert lens.surfaces[-1].thickness == pytest.approx(42.35170011441)
    assert any("VDYN" in n and "not applied" in n for n in lens.notes)
    assert paraxial_data(lens).efl_mm == pytest.approx(49.4, abs=0.05)


def test_aspheric_patent_lens(aspheric):
    lens = aspheric
    assert lens.num_surfaces == 11 and lens.stop_index == 4
    s4 = lens.surfaces[3]
    assert s4.asphere == {4: 1.10721e-5, 6: 1.837e-7}
    assert s4.conic == 0.02 and s4.curvature == pytest.approx(0.1117818019226470)
    assert all(not s.asphere for i, s in enumerate(lens.surfaces) if i != 3)
    assert (lens.aperture_type, lens.aperture_value) == ("fno", 2.1)
    assert lens.field_type == "real_image_height" and lens.fields == [0.0, 8.0, 13.6]
    assert lens.wavelengths_um == F_D_C_UM and lens.wavelength_weights == [1.0, 1.0, 1.0] and lens.primary == 1
    assert lens.surfaces[0].material == CatalogGlass("J-LAK14", "Hikari", None)
    assert lens.surfaces[7].material == CatalogGlass("TAF3", "Hoya", None)


def test_mold_glass_substitute_is_noted_and_gives_the_patent_efl(aspheric):
    lens = aspheric
    assert lens.surfaces[2].material == CatalogGlass("S-TIM28", "Ohara", None)
    assert any("L-TIM28_MOLD" in n and "S-TIM28" in n for n in lens.notes), lens.notes
    assert any("RPO" in n for n in lens.notes)
    assert paraxial_data(lens).efl_mm == pytest.approx(30.8, abs=0.05)


def test_notes_become_warnings(reference_lenses):
    with pytest.warns(GlassSubstitutionWarning, match="L-TIM28_MOLD"):
        load_lens(reference_lenses / ASPHERIC)


@pytest.mark.parametrize("encoding, bom", [("utf-16-le", b"\xff\xfe"), ("utf-16-be", b"\xfe\xff"), ("utf-16-le", b"")])
def test_utf16_loads_identically(tmp_path, reference_lenses, aspheric, encoding, bom):
    p = tmp_path / ASPHERIC
    p.write_bytes(bom + source_text(reference_lenses, ASPHERIC).encode(encoding))
    lens = read_zmx(p)
    assert lens.source == str(p)
    assert lens_to_dict(lens) == lens_to_dict(aspheric)


def error_message(path) -> str:
    with pytest.raises(InputError) as info:
        read_zmx(path)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{path}: "), msg
    return msg


@pytest.mark.parametrize("surface_type", ["TOROIDAL", "BINARY_2", "COORDBRK"])
def test_unsupported_surface_type(tmp_path, reference_lenses, surface_type):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "TYPE EVENASPH", f"TYPE {surface_type}")
    msg = error_message(p)
    assert f"SURF 4 TYPE: unsupported surface type {surface_type}" in msg


def test_malformed_number_names_the_line(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "CURV 7.230657989877079000E-002", "CURV 7.2306x")
    lineno = 1 + source_text(reference_lenses, ASPHERIC).split("\r\n").index(
        '  CURV 7.230657989877079000E-002 0 0 0 0 ""'
    )
    msg = error_message(p)
    assert f": line {lineno} (SURF 3 CURV): expected a number, got '7.2306x'" in msg


def test_missing_stop(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "  STOP\r\n", "")
    assert "STOP: missing the aperture stop" in error_message(p)


def test_unknown_glass_without_model_data_lists_close_names(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "GLAS SF11 0 0", "GLAS SF11Q 0 0")
    msg = error_message(p)
    assert "SURF 6 GLAS: unknown glass 'SF11Q'" in msg
    assert "close names" in msg and "SF11 (Schott)" in msg and "placeholders" in msg


def test_unknown_glass_with_model_data_becomes_a_model_glass(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, DOUBLE_GAUSS, "GLAS N-BALF4 0 0", "GLAS QQ-UNOBTAINIUM 0 0")
    lens = read_zmx(p)
    m = lens.surfaces[4].material
    assert isinstance(m, ModelGlass)
    assert (m.nd_value, m.vd_value) == (1.579559355877, 53.86589845464)
    assert m.nd == pytest.approx(1.579559355877, abs=1e-12)
    assert any("QQ-UNOBTAINIUM" in n and "model glass" in n for n in lens.notes)
    # the pickup on surface 8 still names the catalogue glass
    assert lens.surfaces[7].material == CatalogGlass("N-BALF4", "Schott", None)


def test_blank_model_glass(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "GLAS SF11 0 0 1.5 4.0E+1", "GLAS ___BLANK 1 0 1.78472 2.576E+1")
    m = read_zmx(p).surfaces[5].material
    assert isinstance(m, ModelGlass) and m.nd == pytest.approx(1.78472, abs=1e-12) and m.vd == pytest.approx(25.76)
    p = variant(tmp_path, reference_lenses, ASPHERIC, "GLAS SF11 0 0 1.5 4.0E+1", "GLAS ___BLANK 1 0 1.6 0")
    assert read_zmx(p).surfaces[5].material == ConstantIndex(1.6)


def test_non_mm_units(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "UNIT MM", "UNIT IN")
    assert "(UNIT): expected lens units MM, got IN" in error_message(p)


def test_unsupported_field_type(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "FTYP 3 0 3 3", "FTYP 4 0 3 3")
    assert "(FTYP): unsupported field type 4" in error_message(p)


def test_x_fields_are_refused(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "XFLN 0 0 0", "XFLN 0 0 5")
    assert "(XFLN): field 3 has x = 5" in error_message(p)


def test_object_na_aperture_is_refused(tmp_path, reference_lenses):
    p = variant(tmp_path, reference_lenses, ASPHERIC, "FNUM 2.1 0", "OBNA 0.1 0")
    assert "(OBNA): unsupported system aperture (object-space NA)" in error_message(p)


def test_aperture_variants(tmp_path, reference_lenses):
    lens = read_zmx(variant(tmp_path, reference_lenses, ASPHERIC, "FNUM 2.1 0", "ENPD 14.5"))
    assert (lens.aperture_type, lens.aperture_value) == ("epd", 14.5)
    lens = read_zmx(variant(tmp_path, reference_lenses, ASPHERIC, "FNUM 2.1 0", "FLOA"))
    assert (lens.aperture_type, lens.aperture_value) == ("stop_semi_diameter", 5.2)
    assert paraxial_data(lens).stop_semi_diameter_mm == pytest.approx(5.2, rel=1e-12)
    # paraxial working F/# equals EFL / EPD for an object at infinity
    lens = read_zmx(variant(tmp_path, reference_lenses, ASPHERIC, "FNUM 2.1 0", "FNUM 2.1 1"))
    assert (lens.aperture_type, lens.aperture_value) == ("fno", 2.1)
    assert paraxial_data(lens).working_fno == pytest.approx(2.1, rel=1e-12)


def test_clear_aperture_and_obscuration(tmp_path, reference_lenses):
    stop = '  DIAM 4.215000499256 0 0 0 1 ""\r\n'
    p = variant(tmp_path, reference_lenses, DOUBLE_GAUSS, stop, stop + "  CLAP 0 4.1 0\r\n  OBSC 0 1.5 0\r\n")
    s = read_zmx(p).surfaces[6]
    assert (s.clear_radius, s.obscuration_radius, s.is_stop) == (4.1, 1.5, True)
    p = variant(tmp_path, reference_lenses, DOUBLE_GAUSS, stop, stop + "  SQAP 2 2 0\r\n")
    assert "(SURF 7 SQAP): a rectangular aperture is not rotationally symmetric" in error_message(p)


MIRROR_ZMX = """VERS 140730 73 26155
MODE SEQ
NAME parabola
UNIT MM X W X CM MR CPMM
ENPD 20
FTYP 0 0 1 1 0 0 0
YFLN 0
WAVM 1 0.55 1
PWAV 1
SURF 0
  TYPE STANDARD
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV -5.0E-3
  CONI -1
  GLAS MIRROR 0 0 1.5 40
  DISZ -100
SURF 2
  TYPE STANDARD
  DISZ 0
"""


def test_parabolic_mirror(tmp_path):
    p = tmp_path / "mirror.zmx"
    p.write_text(MIRROR_ZMX)
    lens = read_zmx(p)
    s = lens.surfaces[0]
    assert s.is_mirror and s.material.name == "air" and s.thickness == -100 and s.conic == -1
    assert abs(paraxial_data(lens).efl_mm) == pytest.approx(100.0, rel=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_lens(p)  # no notes: nothing substituted
