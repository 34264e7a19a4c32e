"""optiland models of lensim's lenses, shared by the tests and benchmarks that compare the two.

optiland is a test-only dependency: the lensim package never imports it, and this module
imports it only inside its functions (a benchmark run with its optiland part switched off
needs no optiland). Tests import it as `optiland_models`: pytest's default import mode puts
tests/ (which has no __init__.py) on sys.path, as `from cli_runner import ...` relies on
too; benchmarks add tests/ to sys.path first.

* lensim_glass(material): an optiland material whose index is the lensim material's, so
  that a comparison is of the tracing and not of two glass databases.
* optiland_from_lens(lens, ...): any lensim Lens of refracting, rotationally symmetric
  surfaces (spheres, conics, even aspheres, clear apertures, negative thicknesses in air)
  with an object at infinity and angle fields, built surface by surface in optiland with
  lensim's glass data.
* optiland_cooke(...): the Cooke triplet of tests/data/lenses/README.md (COOKE_TABLE) built
  from the table, with optiland's own catalogue glasses unless told otherwise.
* optiland_pupil, optiland_rms, lensim_rms: optiland's RMS spot radius (its SpotDiagram:
  per wavelength, about the primary-wavelength chief ray, hexapolar rings) and the same
  statistic from lensim's spot diagram on optiland's pupil points.
* assert_agrees_with_optiland(lens, ...): first-order data and those RMS spot radii of a
  lens against optiland_from_lens(lens).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import torch

from lensim.optics.lens import Lens
from lensim.optics.materials import Air, Material
from lensim.optics.spot import spot_diagram

# tests/data/lenses/README.md: radius (mm), thickness (mm), glass as optiland names it
# ((name, catalogue); None: air). optiland's J-SK16 (Hikari) and F2 (Schott) give lensim's
# indices to 2e-16 at 0.55 um (tests/test_psf_peers.py checks it).
COOKE_TABLE = (
    (22.01359, 3.25896, ("J-SK16", "hikari")),
    (-435.76044, 6.00755, None),
    (-22.21328, 0.99997, ("F2", "schott")),
    (20.29192, 4.75041, None),  # stop
    (79.68360, 2.95208, ("J-SK16", "hikari")),
    (-18.39533, 42.20778, None),
)
COOKE_STOP_INDEX = 4  # in optiland's surface list (object surface 0, then the table's surfaces 1-6)
COOKE_EPD_MM = 10.0
COOKE_FIELDS_DEG = (0.0, 14.0, 20.0)
OPTILAND_AIMING = {"paraxial": "paraxial", "real": "iterative"}  # lensim's aiming -> optiland's


@functools.cache
def _lensim_glass_class():
    import optiland.backend as be
    from optiland.materials.base import BaseMaterial

    class LensimGlass(BaseMaterial):
        """An optiland material that returns a lensim material's index (identical glass data)."""

        def __init__(self, material: Material):
            super().__init__()
            self.material = material

        def _calculate_n(self, wavelength, **kwargs):
            return be.array(self.material.index(np.asarray(be.to_numpy(wavelength), dtype=np.float64)))

        def _calculate_k(self, wavelength, **kwargs):
            return be.zeros_like(be.array(np.asarray(be.to_numpy(wavelength), dtype=np.float64)))

        def _cache_state(self):
            return ()  # immutable

    return LensimGlass


def lensim_glass(material: Material):
    """An optiland material (a BaseMaterial) whose refractive index is lensim's
    `material.index` at every wavelength, with no absorption."""
    return _lensim_glass_class()(material)


#: lensim's aperture type -> (optiland's, the factor from lensim's value to optiland's)
OPTILAND_APERTURE = {"epd": ("EPD", 1.0), "fno": ("imageFNO", 1.0), "stop_semi_diameter": ("float_by_stop_size", 2.0)}


def _optiland_surface(s, index: int, defocus: float) -> dict:
    """optiland's Optic.surfaces.add keywords for lensim surface ``s`` at ``index``;
    defocus (mm) is added to its thickness (the image defocus, on the last surface)."""
    import optiland.backend as be
    from optiland.physical_apertures import RadialAperture

    if s.is_mirror:
        raise ValueError("optiland_from_lens: mirrors are not supported")
    kw = dict(
        index=index,
        radius=s.radius,
        thickness=s.thickness + defocus,
        material="air" if isinstance(s.material, Air) else lensim_glass(s.material),
        is_stop=s.is_stop,
    )
    if s.is_aspheric:
        kw.update(
            surface_type="even_asphere",
            conic=s.conic,
            coefficients=[float(s.asphere.get(p, 0.0)) for p in range(2, max(s.asphere) + 1, 2)],
        )
    elif s.conic:
        kw["conic"] = s.conic
    if s.clear_radius is not None or s.obscuration_radius is not None:
        kw["aperture"] = RadialAperture(
            r_max=be.inf if s.clear_radius is None else s.clear_radius, r_min=s.obscuration_radius or 0.0
        )
    return kw


def optiland_from_lens(
    lens: Lens,
    aiming: str = "paraxial",
    fields_deg: Sequence[float] | None = None,
    wavelengths_um: Sequence[float] | None = None,
):
    """The lens in optiland, surface for surface, with lensim's glass data (lensim_glass).

    Object at infinity, angle fields only. Surfaces: radius, thickness (the image defocus
    added to the last one), conic, even-asphere coefficients (optiland's coefficients[0] is
    the r^2 term), clear apertures and obscurations as radial apertures, the stop. System
    aperture from the lens: EPD, image-space F-number (imageFNO) or float by stop size.
    fields_deg: the angle fields (default the lens's); wavelengths_um: default the lens's,
    with its primary (else the first is primary). aiming: lensim's name of the aiming mode
    ('paraxial', or 'real' for optiland's 'iterative' aimer; see tests/test_peers.py for how
    the two aim at the real stop).
    """
    import optiland.backend as be
    from optiland.optic import Optic

    if not lens.infinite_object or lens.field_type != "angle":
        raise ValueError("optiland_from_lens: expected an object at infinity and angle fields")
    op = Optic()
    op.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    last = len(lens.surfaces)
    for i, s in enumerate(lens.surfaces, start=1):
        op.surfaces.add(**_optiland_surface(s, i, lens.image_defocus if i == last else 0.0))
    op.surfaces.add(index=last + 1)
    aperture_type, scale = OPTILAND_APERTURE[lens.aperture_type]
    op.set_aperture(aperture_type=aperture_type, value=scale * lens.aperture_value)
    op.fields.set_type(field_type="angle")
    for a in lens.fields if fields_deg is None else fields_deg:
        op.fields.add(y=float(a))
    if wavelengths_um is None:
        wavelengths_um, primary = lens.wavelengths_um, lens.primary_wavelength_um
    else:
        primary = lens.primary_wavelength_um if lens.primary_wavelength_um in wavelengths_um else wavelengths_um[0]
    for wl in wavelengths_um:
        op.wavelengths.add(value=wl, is_primary=(wl == primary))
    if aiming not in OPTILAND_AIMING:
        raise ValueError(f"expected aiming 'paraxial' or 'real', got {aiming!r}")
    if aiming != "paraxial":  # optiland's default is paraxial aiming
        op.ray_tracer.set_aiming(OPTILAND_AIMING[aiming])
    return op


def optiland_cooke(
    aiming: str = "paraxial",
    stop_semi_diameter_mm: float | None = None,
    materials: Sequence | None = None,
    wavelengths_um: Sequence[float] = (0.55,),
    primary_um: float = 0.55,
):
    """The Cooke triplet of COOKE_TABLE in optiland: EPD 10 mm, angle fields 0 / 14 / 20 deg.

    materials: one optiland material for each glass of the table, in order (SK16, F2,
    SK16): a (name, catalogue) pair or a material such as lensim_glass(...); default the
    table's catalogue glasses. wavelengths_um: with primary_um the primary.
    aiming 'paraxial': optiland's default (rays aimed at the paraxial entrance pupil).
    aiming 'real': iterative aiming at the stop points (px, py) x stop_semi_diameter_mm,
    lensim's paraxial stop semi-diameter, via optiland's 'float_by_stop_size' aperture
    (paraxial EPD unchanged at 10 mm).
    """
    import optiland.backend as be
    from optiland.optic import Optic

    glass_rows = [k for k, row in enumerate(COOKE_TABLE) if row[2] is not None]
    if materials is not None and len(materials) != len(glass_rows):
        raise ValueError(f"expected {len(glass_rows)} materials (one per glass of the table), got {len(materials)}")
    chosen = dict(zip(glass_rows, materials, strict=True)) if materials is not None else {}
    o = Optic()
    o.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    for k, (radius, thickness, glass) in enumerate(COOKE_TABLE):
        material = "air" if glass is None else chosen.get(k, glass)
        o.surfaces.add(
            index=k + 1, radius=radius, thickness=thickness, material=material, is_stop=(k + 1 == COOKE_STOP_INDEX)
        )
    o.surfaces.add(index=len(COOKE_TABLE) + 1)
    o.set_aperture(aperture_type="EPD", value=COOKE_EPD_MM)
    o.fields.set_type(field_type="angle")
    for y in COOKE_FIELDS_DEG:
        o.fields.add(y=y)
    for wl in wavelengths_um:
        o.wavelengths.add(value=wl, is_primary=(wl == primary_um))
    if aiming == "real":
        if stop_semi_diameter_mm is None:
            raise ValueError("optiland_cooke: real aiming needs stop_semi_diameter_mm")
        o.set_aperture(aperture_type="float_by_stop_size", value=2.0 * stop_semi_diameter_mm)
        o.surfaces[COOKE_STOP_INDEX].semi_aperture = stop_semi_diameter_mm
        o.ray_tracer.set_aiming("iterative", max_iter=50, tol=1e-12)
    elif aiming != "paraxial":
        raise ValueError(f"expected aiming 'paraxial' or 'real', got {aiming!r}")
    return o


def optiland_pupil(rings: int = 6) -> torch.Tensor:
    """optiland's hexapolar pupil points (its SpotDiagram's pattern: centre, then rings of
    6, 12, ... points) as normalized pupil coordinates (P, 2) for lensim."""
    import optiland.backend as be
    from optiland.distribution import HexagonalDistribution

    d = HexagonalDistribution()
    d.generate_points(rings)
    return torch.as_tensor(np.stack([be.to_numpy(d.x), be.to_numpy(d.y)], -1), dtype=torch.float64)


def optiland_rms(op, hy: Sequence[float], rings: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """optiland's RMS spot radii (F, W) in mm at the normalized fields (0, hy) and the
    number of rays it kept (F, W): its SpotDiagram over all wavelengths."""
    import optiland.backend as be
    from optiland.analysis import SpotDiagram

    sd = SpotDiagram(op, fields=[(0.0, h) for h in hy], wavelengths="all", num_rings=rings)
    rms = np.array([[float(r) for r in per_field] for per_field in sd.rms_spot_radius()])
    kept = np.array([[int(np.size(be.to_numpy(w.x))) for w in per_field] for per_field in sd.data])
    return rms, kept


def lensim_rms(lens: Lens, fields: Sequence[float], pupil: torch.Tensor, aiming: str) -> tuple[np.ndarray, np.ndarray]:
    """optiland's statistic from lensim's spot diagram at `fields` (lens units) over the
    pupil points: (F, W) RMS radius (mm) about the primary-wavelength chief ray, and the
    number of unvignetted rays (F, W)."""
    sd = spot_diagram(lens, list(fields), None, pupil, aiming)
    ref = sd.chief[sd.primary]  # (F, 2)
    d2 = ((sd.xy - ref[None, :, None, :]) ** 2).sum(-1)
    v = sd.valid.to(torch.float64)
    rms = torch.sqrt((d2 * v).sum(-1) / v.sum(-1))
    return rms.T.numpy(), v.sum(-1).T.numpy().astype(int)


def assert_agrees_with_optiland(
    lens: Lens, rms_rtol: float, fractions: Sequence[float] = (0.0, 0.7, 1.0), rings: int = 6
) -> np.ndarray:
    """Check a lens against its optiland model (optiland_from_lens, paraxial aiming): EFL,
    F-number and entrance-pupil position to 1e-9; at the field fractions, the same rays
    vignetted and optiland's RMS spot radii (F, W) within rms_rtol. Returns lensim's
    radii (F, W) in mm."""
    from lensim.optics.paraxial import paraxial_data

    op = optiland_from_lens(lens)
    para = paraxial_data(lens)
    np.testing.assert_allclose(float(op.paraxial.f2()), para.efl_mm, rtol=1e-9)
    np.testing.assert_allclose(float(op.paraxial.FNO()), para.fno, rtol=1e-9)
    np.testing.assert_allclose(float(op.paraxial.EPL()), para.entrance_pupil_z_mm, rtol=0, atol=1e-9)
    ref, ref_kept = optiland_rms(op, fractions, rings)
    ours, kept = lensim_rms(lens, [f * lens.max_field for f in fractions], optiland_pupil(rings), "paraxial")
    np.testing.assert_array_equal(kept, ref_kept)
    np.testing.assert_allclose(ours, ref, rtol=rms_rtol)
    return ours
