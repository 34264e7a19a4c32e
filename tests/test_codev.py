"""CODE V .seq import: the double Gauss against its published real-ray trace (1e-5 mm),
the paraxial image solve, the built-in conversion, and one-line errors on bad input."""

import math
import warnings

import numpy as np
import pytest
import torch

from lensim.errors import InputError
from lensim.optics.aiming.rays import generate_rays
from lensim.optics.codev import read_seq
from lensim.optics.lens_file import GlassSubstitutionWarning, load_lens
from lensim.optics.materials import CatalogGlass, ModelGlass
from lensim.optics.paraxial import paraxial_data
from lensim.optics.trace import trace

# tests/data/lenses/README.md: axial marginal ray, 587.6 nm, entering parallel at 25 mm
TRUTH_HEIGHTS = [
    25.000000,
    24.109772,
    22.844992,
    20.958242,
    16.784894,
    15.702464,
    14.610682,
    15.815163,
    16.882946,
    16.583956,
    16.261006,
]
TRUTH_IMAGE_HEIGHT = 0.014138
TRUTH_TAN_U = -0.258832
TOL_MM = 1e-5


@pytest.fixture(scope="module")
def dblgauss(reference_lenses):
    return read_seq(reference_lenses / "ag_dblgauss.seq")


def marginal_ray(lens):
    """Heights (mm) at every surface then the image, and the image-space tan U."""
    rays, wl = generate_rays(lens, [0.0], torch.tensor([[0.0, 1.0]], dtype=torch.float64), [0.5876], "paraxial")
    res = trace(lens, rays, wl, record=True)
    assert bool(res.rays.valid.all())
    heights = res.surface_positions[:, 0, 0, 0, 1].numpy()
    d = res.rays.direction[0, 0, 0]
    return heights, float(d[1] / d[2])


def test_marginal_ray_matches_published_trace(dblgauss):
    heights, tan_u = marginal_ray(dblgauss)
    assert len(heights) == 12
    np.testing.assert_allclose(heights[:11], TRUTH_HEIGHTS, rtol=0, atol=TOL_MM)
    assert heights[11] == pytest.approx(TRUTH_IMAGE_HEIGHT, abs=TOL_MM)
    assert tan_u == pytest.approx(TRUTH_TAN_U, abs=TOL_MM)


def test_system_data(dblgauss):
    lens = dblgauss
    assert lens.name == "Double Gauss F/2 -  Available Glasses"
    assert lens.num_surfaces == 11 and lens.stop_index == 5
    assert (lens.aperture_type, lens.aperture_value) == ("epd", 50.0)
    assert lens.field_type == "angle"
    np.testing.assert_allclose(lens.fields, [0.0, 10.0, 14.0], atol=1e-8)
    np.testing.assert_allclose(lens.wavelengths_um, [0.6563, 0.5876, 0.4861], rtol=1e-12)
    assert lens.primary == 1 and lens.wavelength_weights == [1.0, 1.0, 1.0]
    assert math.isinf(lens.object_distance)
    assert lens.image_defocus == pytest.approx(-0.4002686453541377, abs=1e-15)
    # RDM N: the numbers are curvatures
    assert lens.surfaces[0].curvature == pytest.approx(0.01779284094091543, rel=1e-15)
    assert [s.material for s in lens.surfaces if isinstance(s.material, CatalogGlass)] == [
        CatalogGlass("N-SSK2", "Schott", None),
        CatalogGlass("N-SK2", "Schott", None),
        CatalogGlass("F5", "Schott", None),
        CatalogGlass("F5", "Schott", None),
        CatalogGlass("N-SK16", "Schott", None),
        CatalogGlass("N-SK16", "Schott", None),
    ]
    assert any("VUY" in n and "not applied" in n for n in lens.notes)
    assert paraxial_data(lens).efl_mm == pytest.approx(100.0, abs=0.01)


def test_pim_solve_puts_the_image_at_the_paraxial_focus(dblgauss, reference_lenses, tmp_path):
    # the file's own value is the solve's result
    assert dblgauss.surfaces[-1].thickness == pytest.approx(61.4875364179821, abs=1e-9)
    text = (reference_lenses / "ag_dblgauss.seq").read_text()
    assert "61.4875364179821" in text
    moved = tmp_path / "moved.seq"
    moved.write_text(text.replace("61.4875364179821", "50.0"))
    assert read_seq(moved).surfaces[-1].thickness == pytest.approx(61.4875364179821, abs=1e-9)
    # without PIM the written thickness stays
    fixed = tmp_path / "fixed.seq"
    fixed.write_text(text.replace("61.4875364179821", "50.0").replace("  PIM", ""))
    assert read_seq(fixed).surfaces[-1].thickness == 50.0


def test_builtin_double_gauss_is_the_same_lens(dblgauss):
    with warnings.catch_warnings():
        warnings.simplefilter("error", GlassSubstitutionWarning)
        builtin = load_lens("double_gauss")
    h_seq, t_seq = marginal_ray(dblgauss)
    h_yaml, t_yaml = marginal_ray(builtin)
    np.testing.assert_allclose(h_yaml, h_seq, rtol=0, atol=1e-9)
    assert t_yaml == pytest.approx(t_seq, abs=1e-12)
    np.testing.assert_allclose(h_yaml[:11], TRUTH_HEIGHTS, rtol=0, atol=TOL_MM)
    assert builtin.image_defocus == dblgauss.image_defocus
    assert builtin.wavelengths_um == dblgauss.wavelengths_um and builtin.primary == dblgauss.primary


SINGLET = """RDM
LEN "test singlet"
DIM M
EPD 10
WL 550
YAN 0 5
SO 0 1e11
S 50 5 BK7
  STO
  K -0.5; ASP; A 1e-6; B -2e-9
  CIR 6 ! clear semi-diameter
S -200 90
SI 0 0.25
GO
"""


def write(tmp_path, text, name="lens.seq"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_radius_mode_asphere_and_bare_glass_name(tmp_path):
    lens = read_seq(write(tmp_path, SINGLET))
    s = lens.surfaces[0]
    assert s.curvature == pytest.approx(1 / 50) and lens.surfaces[1].curvature == pytest.approx(-1 / 200)
    assert (s.conic, s.asphere, s.clear_radius, s.is_stop) == (-0.5, {4: 1e-6, 6: -2e-9}, 6.0, True)
    assert s.material.name == "N-BK7"
    assert any("BK7" in n and "N-BK7" in n for n in lens.notes)
    assert lens.name == "test singlet" and lens.fields == [0.0, 5.0] and lens.image_defocus == 0.25


@pytest.mark.parametrize(
    "old, new, field, words",
    [
        ("S 50 5 BK7", "S 50 5 BK7\n  XDE 1.0", "line 9 (XDE)", ["unsupported", "XDE"]),
        ("DIM M", "DIM I", "line 3 (DIM)", ["millimetres"]),
        ("S -200 90", "S -2OO 90", "line 12 (S 2)", ["number", "-2OO"]),
        ("  STO\n", "", "STO", ["missing", "stop"]),
        ("S 50 5 BK7", "S 50 5 NOSUCHGLASS_SCHOTT", "line 8 (S 1 glass)", ["unknown glass", "close names"]),
        ("YAN 0 5", "YAN 0 5\nXAN 0 3", "line 7 (XAN)", ["rotationally symmetric"]),
    ],
)
def test_bad_input_names_file_and_field(tmp_path, old, new, field, words):
    assert old in SINGLET
    p = write(tmp_path, SINGLET.replace(old, new))
    with pytest.raises(InputError) as info:
        read_seq(p)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{p}: {field}: "), msg
    for w in words:
        assert w in msg, msg


def test_mirror_keeps_the_incident_medium(tmp_path):
    text = "RDM\nDIM M\nEPD 20\nWL 550\nYAN 0\nSO 0 1e11\nS -200 -100 REFL\nSTO\nSI 0 0\nGO\n"
    lens = read_seq(write(tmp_path, text))
    s = lens.surfaces[0]
    assert s.is_mirror and s.material.name == "air" and s.thickness == -100
    assert abs(paraxial_data(lens).efl_mm) == pytest.approx(100.0, rel=1e-12)
    assert not isinstance(s.material, ModelGlass)
