"""Focusing at a distance lands on the best focus (issue 25, defect 1), checked against a
brute-force scan of the image plane with a full retrace at every plane."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lensim.errors import InputError
from lensim.optics.lens_file import lens_to_dict, load_lens
from lensim.optics.shooting import ShootingSettings, lens_at
from lensim.optics.spot import rms_spot_radius
from lensim.psf.best_focus import FOCUS_SAMPLES, best_focus_shift
from lensim.psf.mtf import refocused
from lensim.psf.wavefront import remove_piston_tilt, wavefront

CATADIOPTRIC = "lensim/assets/library/catadioptric_f1.25_hoo_ex27.yaml"


def _scan_error(lens, shift_mm: float) -> float:
    """The criterion at one image plane by a full retrace of the refocused lens: the
    weighted mean squared RMS wavefront (waves^2) on axis over the lens's wavelengths."""
    moved = refocused(lens, shift_mm)
    total = 0.0
    for wl, w in zip(lens.wavelengths_um, lens.wavelength_weights, strict=True):
        wf = wavefront(moved, 0.0, wl, FOCUS_SAMPLES, "real")
        total += w * float(np.mean(remove_piston_tilt(wf.pupil_xy, wf.opd_waves) ** 2))
    return total / sum(lens.wavelength_weights)


@pytest.fixture(scope="module")
def f125_at_1m():
    """The F/1.25 catadioptric focused at 1 m, paraxially (as before) and to best focus."""
    lens = load_lens(CATADIOPTRIC)
    return {mode: lens_at(lens, ShootingSettings(focus_m=1.0, focus_mode=mode)) for mode in ("paraxial", "best")}


def test_best_focus_is_the_minimum_of_a_brute_force_scan(f125_at_1m) -> None:
    best = f125_at_1m["best"]
    # the scan: 41 planes over +-40 um around the plane focusing chose, each retraced
    shifts = np.linspace(-0.04, 0.04, 41)
    errors = np.array([_scan_error(best, z) for z in shifts])
    k = int(np.argmin(errors))
    assert 0 < k < len(shifts) - 1  # the minimum is inside the scan
    a, b, _ = np.polyfit(shifts[k - 3 : k + 4], errors[k - 3 : k + 4], 2)
    scan_best = -b / (2 * a)
    assert abs(scan_best) < 0.5e-3  # the focused plane is within 0.5 um of the scan's minimum
    assert _scan_error(best, 0.0) <= errors.min() + 1e-6
    # and it is not where paraxial focusing put it (the case: 28 um away)
    para = f125_at_1m["paraxial"]
    assert para.surfaces[-1].thickness - best.surfaces[-1].thickness > 0.02


def test_best_focus_sharpens_the_f125_lens_at_1m(f125_at_1m) -> None:
    # RMS spot on axis: 14.5 um at the paraxial focus, 6.7 um at minimum RMS wavefront
    para = rms_spot_radius(f125_at_1m["paraxial"], 0.0, aiming="real") * 1e3
    best = rms_spot_radius(f125_at_1m["best"], 0.0, aiming="real") * 1e3
    assert para > 12.0 and best < 0.5 * para


def test_best_focus_shift_finds_a_known_defocus() -> None:
    # a lens moved off its best focus by a known amount is moved back by that amount
    lens = load_lens(CATADIOPTRIC)
    z0 = best_focus_shift(lens)
    assert best_focus_shift(refocused(lens, 0.01)) == pytest.approx(z0 - 0.01, abs=2e-5)


def test_calibrated_focus_keeps_the_file_at_its_own_distance_and_follows_the_best_focus() -> None:
    lens = load_lens("cooke_triplet")
    # at the file's own distance (infinity) the lens is the file's: as before this change
    for mode in ("calibrated", "paraxial"):
        at = lens_at(lens, ShootingSettings(focus_m=math.inf, focus_mode=mode))
        assert lens_to_dict(at)["surfaces"] == lens_to_dict(lens)["surfaces"]
    # the file's plane sits off its on-axis best focus (a field balance); at 1 m it keeps
    # that offset from the best focus, where paraxial focusing does not
    offset_inf = best_focus_shift(lens)
    at = lens_at(lens, ShootingSettings(focus_m=1.0))
    assert best_focus_shift(at) == pytest.approx(offset_inf, abs=2e-4)
    best = lens_at(lens, ShootingSettings(focus_m=math.inf, focus_mode="best"))
    assert abs(best_focus_shift(best)) < 2e-4 and abs(offset_inf) > 0.05


def test_the_focus_mode_is_checked_and_recorded() -> None:
    with pytest.raises(InputError, match="focus_mode: expected one of calibrated, best, paraxial"):
        ShootingSettings(focus_m=1.0, focus_mode="sharpest")
    s = ShootingSettings(focus_m=2.0, focus_mode="paraxial")
    assert s.to_dict()["focus_mode"] == "paraxial"
    assert ShootingSettings.from_dict(s.to_dict()) == s
    assert "focus_mode" not in ShootingSettings(focus_m=2.0).to_dict()
    assert ShootingSettings.from_text(focus_m="2", focus_mode="Best").focus_mode == "best"
