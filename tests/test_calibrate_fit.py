"""As-built calibration recovers known perturbations from edge MTFs (lensim.calibrate.fit)."""

import math

import numpy as np
import pytest

from lensim.calibrate.fit import CoverageError, Observations, fit
from lensim.calibrate.model import Edge, edge_mtf, model_mtfs
from lensim.calibrate.tolerances import perturbed_lens
from lensim.optics.lens_file import load_lens
from lensim.psf.mtf import field_otf

FREQ = (10.0, 25.0, 40.0, 55.0, 70.0)


def _edges(radii=(0.0, 10.0), azimuths=(45.0, 135.0, 225.0, 315.0)) -> list[Edge]:
    out = []
    for r in radii:
        for a in azimuths if r else (0.0,):
            x, y = r * math.cos(math.radians(a)), r * math.sin(math.radians(a))
            out += [Edge(x, y, 0.0, FREQ), Edge(x, y, 90.0, FREQ)]
    return out


def test_edge_mtf_matches_the_sagittal_and_tangential_mtf():
    lens = load_lens("cooke_triplet", warn=False)
    wl, w = lens.wavelengths_um, lens.wavelength_weights
    probe = lens.with_changes(field_type="paraxial_image_height", fields=[12.0])
    sag, tan = field_otf(probe, 12.0, wl, w, 32, "paraxial").mtf(FREQ)
    assert edge_mtf(lens, Edge(0.0, 12.0, 0.0, FREQ), wl, w) == pytest.approx(sag, abs=1e-12)
    assert edge_mtf(lens, Edge(0.0, 12.0, 90.0, FREQ), wl, w) == pytest.approx(tan, abs=1e-12)
    # on the x axis the radial direction is x; on the diagonal the radial one is 45 deg
    assert edge_mtf(lens, Edge(12.0, 0.0, 0.0, FREQ), wl, w) == pytest.approx(tan, abs=1e-9)
    d = 12.0 / math.sqrt(2.0)
    assert edge_mtf(lens, Edge(-d, d, 135.0, FREQ), wl, w) == pytest.approx(tan, abs=1e-9)


def test_calibration_recovers_a_focus_offset_and_an_element_decentre():
    lens = load_lens("cooke_triplet", warn=False)
    truth = {"image.focus": 0.025, "e2.decentre_x": 0.02, "e2.decentre_y": -0.01}
    edges = _edges()
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    rng = np.random.default_rng(1)
    measured = [m + rng.normal(0.0, 0.003, m.shape) for m in model_mtfs(perturbed_lens(lens, truth), edges, wl, w, 16)]
    obs = Observations(edges, measured, None, wl, w, samples=16)
    result = fit(lens, obs, names=list(truth))
    for name, value in truth.items():
        assert result.values[name] == pytest.approx(value, abs=max(4 * result.sigma[name], 0.002)), name
        assert 0 < result.sigma[name] < 0.005
    assert result.rms_after < 0.006 < result.rms_before
    assert result.lens.as_built["parameters"] == pytest.approx(result.values)
    assert result.lens.as_built["uncertainties"] == pytest.approx(result.sigma)


def test_calibration_refuses_what_the_chart_cannot_see():
    # edges on the y axis only: a sensor tilt about y changes nothing there
    lens = load_lens("cooke_triplet", warn=False)
    edges = _edges(radii=(0.0, 10.0), azimuths=(90.0, 270.0))
    wl, w = list(lens.wavelengths_um), list(lens.wavelength_weights)
    obs = Observations(edges, model_mtfs(lens, edges, wl, w, 16), None, wl, w, samples=16)
    with pytest.raises(CoverageError) as e:
        fit(lens, obs, names=["image.focus", "image.tilt_y"], where="photo.png")
    assert e.value.field == "image.tilt_y" and str(e.value).startswith("photo.png: image.tilt_y: ")
    assert "\n" not in str(e.value)
