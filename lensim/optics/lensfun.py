"""Export a lens's distortion, lateral colour and vignetting as a lensfun profile.

lensfun (darktable, RawTherapee, Hugin; checked here with lensfunpy, which bundles lensfun
0.3.4) describes a lens by fitted models, each with its own radius unit:

* distortion, model "ptlens": Rd = Ru (a Ru^3 + b Ru^2 + c Ru + 1 - a - b - c), Ru the
  undistorted (ideal, rectilinear) radius and Rd the real one, r = 1 at half the short
  side of a 3:2 frame at the profile's crop factor (12 mm / crop factor on the sensor).
  r = 1 is a fixed point of the model, so the ideal image's scale is the one that makes
  it so: lensim fits Rd = k u P(k u), u the paraxial height in the same unit, with the
  scale k free (a linear fit in u, u^2, u^3, u^4, then k from its quartic).
* lateral colour, model "poly3": r_c = r_g (b r_g^2 + c r_g + v) for c = red, blue, r_g
  the green channel's real radius (same unit as distortion); v > 1: that channel's image
  is larger. Fitted to the channel-weighted chief rays (field_analysis.lateral_colour).
* vignetting, model "pa": 1 + k1 r^2 + k2 r^4 + k3 r^6 with r = 1 at the corner of the
  3:2 frame; fitted to the relative illumination at the profile's f-number.

All fits use fields from the axis to the frame's corner (the lens must cover it).
Lengths in mm, wavelengths in nm at the interface.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lensim.errors import InputError, LensimError, ParameterError, renamed
from lensim.io import atomic_write_text
from lensim.optics.aiming import Aiming
from lensim.optics.aiming.rays import object_field
from lensim.optics.field_analysis import distortion, lateral_colour, relative_illumination
from lensim.optics.lens import Lens
from lensim.optics.paraxial import paraxial_data
from lensim.optics.shooting import ShootingSettings, lens_at

HALF_SHORT_SIDE_FULL_FRAME_MM = 12.0  # lensfun's distortion/TCA radius unit at crop factor 1
CORNER_IN_SHORT_HALF_SIDES = math.sqrt(13.0) / 2.0  # 3:2 frame: corner radius / half short side
INFINITY_DISTANCE_M = 1000.0  # what lensfun's database writes for focus at infinity
FIT_FIELDS = 25


@dataclass
class LensfunProfile:
    """A lensfun lens entry and how well its models fit lensim's rays.

    crop_factor, focal_mm, aperture (f-number), distance_m: the shooting settings the
    models hold for. distortion {a, b, c}; distortion_scale: k, the ideal image's scale
    relative to the paraxial one; tca {vr, cr, br, vb, cb, bb}; vignetting {k1, k2, k3}.
    fit: largest residual of each model (distortion and tca in um on the sensor,
    vignetting in relative illumination). samples: the fitted data (heights in mm).
    """

    maker: str
    model: str
    mount: str
    crop_factor: float
    focal_mm: float
    aperture: float
    distance_m: float
    distortion: dict[str, float]
    distortion_scale: float
    tca: dict[str, float]
    vignetting: dict[str, float]
    fit: dict[str, float]
    samples: dict[str, list[float]] = field(repr=False)
    source: str = ""

    @property
    def unit_mm(self) -> float:
        """lensfun's distortion and TCA radius unit on the sensor (mm)."""
        return HALF_SHORT_SIDE_FULL_FRAME_MM / self.crop_factor


def check_settings(
    maker: str, model: str, mount: str, crop_factor: float, focal_mm: float, aperture: float, distance_m: float | None
) -> None:
    """One-line errors (ParameterError) for every bad setting, before any work."""
    for name, text in (("maker", maker), ("model", model), ("mount", mount)):
        if not str(text).strip():
            raise ParameterError(None, name, "expected a non-empty name")
    for name, value in (("crop_factor", crop_factor), ("focal_mm", focal_mm), ("aperture", aperture)):
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(None, name, f"expected a positive number, got {value:g}")
    if distance_m is not None and not (math.isfinite(distance_m) and distance_m > 0):
        raise ParameterError(None, "distance_m", f"expected a positive focus distance in metres, got {distance_m:g}")


def _corner_launch(lens: Lens, corner_mm: float, crop_factor: float, aiming: Aiming) -> float:
    """The launch field whose real chief ray lands on the frame's corner (mm)."""
    probe = lens.with_changes(field_type="real_image_height", fields=[corner_mm])
    try:
        return object_field(probe, corner_mm, aiming, paraxial_data(probe))
    except LensimError as e:
        raise ParameterError(
            lens.source,
            "crop_factor",
            f"the lens does not reach the corner of a 3:2 frame at crop "
            f"factor {crop_factor:g} ({corner_mm:.3f} mm image height): "
            f"{str(e).split(': ')[-1]}",
        ) from None


def _fit_ptlens(u: np.ndarray, rd: np.ndarray) -> tuple[dict[str, float], float, np.ndarray]:
    """ptlens a, b, c and the scale k with rd = k u P(k u), P(1) = 1; and the fitted rd."""
    basis = np.stack([u**4, u**3, u**2, u], axis=1)
    (alpha, beta, gamma, delta), *_ = np.linalg.lstsq(basis, rd, rcond=None)
    # rd = a k^4 u^4 + b k^3 u^3 + c k^2 u^2 + k (1 - a - b - c) u  =>  k^4 - delta k^3 - gamma k^2 - beta k - alpha = 0
    roots = np.roots([1.0, -delta, -gamma, -beta, -alpha])
    real = [float(r.real) for r in roots if abs(r.imag) < 1e-9 and r.real > 0]
    if not real:
        raise InputError(None, "distortion", "no ptlens model fits this lens's distortion")
    k = min(real, key=lambda r: abs(r - delta))
    coef = {"a": alpha / k**4, "b": beta / k**3, "c": gamma / k**2}
    return coef, k, basis @ np.array([alpha, beta, gamma, delta])


def _fit_poly3(rg: np.ndarray, rc: np.ndarray) -> tuple[tuple[float, float, float], np.ndarray]:
    """(v, c, b) of rc = rg (b rg^2 + c rg + v), least squares in rc; and the fitted rc."""
    basis = np.stack([rg, rg**2, rg**3], axis=1)
    coef, *_ = np.linalg.lstsq(basis, rc, rcond=None)
    return (float(coef[0]), float(coef[1]), float(coef[2])), basis @ coef


def _fit_pa(r: np.ndarray, ri: np.ndarray) -> tuple[dict[str, float], np.ndarray]:
    """k1, k2, k3 of ri = 1 + k1 r^2 + k2 r^4 + k3 r^6 (least squares); and the fitted ri."""
    basis = np.stack([r**2, r**4, r**6], axis=1)
    coef, *_ = np.linalg.lstsq(basis, ri - 1.0, rcond=None)
    return {"k1": float(coef[0]), "k2": float(coef[1]), "k3": float(coef[2])}, 1.0 + basis @ coef


def lensfun_profile(
    lens: Lens,
    maker: str,
    model: str,
    mount: str,
    crop_factor: float,
    focal_mm: float,
    aperture: float,
    wavelengths_nm: np.ndarray,
    channel_weights: np.ndarray,
    distance_m: float | None = None,
    aiming: Aiming = "real",
    ri_samples: int = 32,
) -> LensfunProfile:
    """Fit lensfun's ptlens, poly3 and pa models to the lens at F-number `aperture` (and
    focused at distance_m metres from the image plane, default the lens's own object
    distance; lensim.optics.shooting.lens_at) over FIT_FIELDS fields
    from the axis to the corner of a 3:2 frame at crop_factor. Lateral colour is weighted
    by channel_weights (3, W) at wavelengths_nm (W,), rows R, G, B (a SpectralResponse's)."""
    check_settings(maker, model, mount, crop_factor, focal_mm, aperture, distance_m)
    try:
        set_lens = lens_at(lens, ShootingSettings(fno=aperture, focus_m=distance_m))
    except ParameterError as e:  # lens_at's settings are this function's aperture and distance_m
        raise renamed(e, {"fno": "aperture", "focus_m": "distance_m", "object_m": "distance_m"}) from None
    unit = HALF_SHORT_SIDE_FULL_FRAME_MM / crop_factor
    corner = unit * CORNER_IN_SHORT_HALF_SIDES
    probe = set_lens.launch_lens()
    top = _corner_launch(set_lens, corner, crop_factor, aiming)
    if probe.launch_field_type == "angle":  # equal steps of paraxial height: tan(angle)
        launch = [math.degrees(math.atan(t)) for t in np.linspace(0.0, math.tan(math.radians(top)), FIT_FIELDS)]
    else:
        launch = list(np.linspace(0.0, top, FIT_FIELDS))
    dist = distortion(probe, launch, aiming)
    colour = lateral_colour(probe, launch, wavelengths_nm, channel_weights, aiming)
    ri = relative_illumination(probe, launch, samples=ri_samples, aiming=aiming)
    u = np.array(dist["paraxial_height_mm"]) / unit
    r_rgb = np.array(colour["channel_height_mm"]).T / unit  # (3, F)
    coef, k, rd_fit = _fit_ptlens(u, r_rgb[1])
    (vr, cr, br), red_fit = _fit_poly3(r_rgb[1], r_rgb[0])
    (vb, cb, bb), blue_fit = _fit_poly3(r_rgb[1], r_rgb[2])
    r_corner = r_rgb[1] / CORNER_IN_SHORT_HALF_SIDES
    vig, ri_fit = _fit_pa(r_corner, np.array(ri["relative_illumination"]))
    fit = {
        "distortion_um": float(np.abs(rd_fit - r_rgb[1]).max() * unit * 1000.0),
        "tca_um": float(max(np.abs(red_fit - r_rgb[0]).max(), np.abs(blue_fit - r_rgb[2]).max()) * unit * 1000.0),
        "vignetting": float(np.abs(ri_fit - np.array(ri["relative_illumination"])).max()),
    }
    distance = (
        distance_m
        if distance_m is not None
        else (
            INFINITY_DISTANCE_M
            if set_lens.infinite_object
            else (set_lens.object_distance + set_lens.total_track) / 1000.0
        )
    )
    samples = {
        "launch": list(map(float, launch)),
        "paraxial_height_mm": dist["paraxial_height_mm"],
        "channel_height_mm": np.array(colour["channel_height_mm"]).T.tolist(),
        "relative_illumination": ri["relative_illumination"],
    }
    return LensfunProfile(
        maker.strip(),
        model.strip(),
        mount.strip(),
        float(crop_factor),
        float(focal_mm),
        float(aperture),
        float(distance),
        coef,
        float(k),
        {"vr": vr, "cr": cr, "br": br, "vb": vb, "cb": cb, "bb": bb},
        vig,
        fit,
        samples,
        lens.source,
    )


def _num(x: float) -> str:
    return f"{x:.9g}"


def profile_xml(profile: LensfunProfile) -> str:
    """The profile as a lensfun database file (lensdatabase version 1, one <lens>)."""
    root = ET.Element("lensdatabase", version="1")
    lens = ET.SubElement(root, "lens")
    for tag, text in (
        ("maker", profile.maker),
        ("model", profile.model),
        ("mount", profile.mount),
        ("cropfactor", _num(profile.crop_factor)),
    ):
        ET.SubElement(lens, tag).text = text
    cal = ET.SubElement(lens, "calibration")
    cal.append(
        ET.Comment(
            f" lensim: fitted to real chief rays of {Path(profile.source).name}; largest residuals: "
            f"distortion {profile.fit['distortion_um']:.3g} um, TCA {profile.fit['tca_um']:.3g} um, "
            f"vignetting {profile.fit['vignetting']:.2g} "
        )
    )
    focal = {"focal": _num(profile.focal_mm)}
    vignetting_at = focal | {"aperture": _num(profile.aperture), "distance": _num(profile.distance_m)}
    models = (
        ("distortion", "ptlens", focal, profile.distortion),
        ("tca", "poly3", focal, profile.tca),
        ("vignetting", "pa", vignetting_at, profile.vignetting),
    )
    for tag, model, at, terms in models:
        ET.SubElement(cal, tag, attrib={"model": model} | at | {k: _num(v) for k, v in terms.items()})
    ET.indent(root, space="    ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_profile(profile: LensfunProfile, path: str | Path) -> None:
    """Write the lensfun database file atomically (.xml)."""
    path = Path(path)
    if path.suffix.lower() != ".xml":
        raise ParameterError(str(path), "path", "expected a .xml file name (a lensfun database file)")
    atomic_write_text(path, profile_xml(profile))
