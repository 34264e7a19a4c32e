"""`lensim lens mtf / wavefront / fans / field-curves / energy`: the analyses a lens
designer reads (diffraction MTF, wavefront and Zernike terms, ray fans, field curvature,
encircled and ensquared energy), registered on the `lens` group of lensim.cli.lens_cmd.

Every option is checked before any work (one-line errors, exit status 2); the library
computes (lensim.psf.analysis_reports, lensim.optics.fans) and draws
(lensim.plots.analysis)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from lensim.cli.bank_options import config_option, fno_option, focus_m_option, focus_mode_option, object_m_option
from lensim.cli.common import console, print_json, progress_bar
from lensim.cli.lens_cmd import (
    FIELD_DEG_HELP,
    FIELD_HELP,
    IMAGE_HEIGHT_HELP,
    LENS_ARG,
    AimingChoice,
    _check_figure_name,
    _load,
    lens_app,
)
from lensim.cli.validate import at_least, choice, in_range, positive, wavelength_nm
from lensim.errors import InputError
from lensim.psf.defaults import DEFAULT_WAVELENGTHS_TEXT, METHODS, psf_method

if TYPE_CHECKING:
    from lensim.optics.lens import Lens

OUTPUT_HELP = "Figure to write (.png, .pdf or .svg)."
CHANNELS = ("r", "g", "b", "all")
SENSOR_HELP = (
    "Sensor profile (file or built-in name): its spectral response weights the wavelengths "
    f"(default {DEFAULT_WAVELENGTHS_TEXT} nm) and its pixel pitch sets the default frequencies (Nyquist/4 and /2)."
)
CHANNEL_HELP = "With --sensor: the channel whose response weights the wavelengths (r, g, b, or all: their sum)."
WAVELENGTHS_HELP = (
    "Wavelengths in nm, START:STOP:STEP or a comma list (default: the lens file's, with its weights; "
    "equal weights unless --sensor)."
)
PUPIL_HELP = "Pupil grid samples across the diameter."
#: zernike conventions and term limits (lensim.psf.zernike), kept here so --help loads no NumPy
ZERNIKE_CONVENTIONS = ("noll", "fringe")
ZERNIKE_MAX_TERMS = {"noll": 231, "fringe": 37}


FIELD_OPTION = typer.Option(None, "--field", help=FIELD_HELP)
FIELD_DEG_OPTION = typer.Option(None, "--field-deg", help=FIELD_DEG_HELP)
IMAGE_HEIGHT_OPTION = typer.Option(None, "--image-height-mm", help=IMAGE_HEIGHT_HELP)
ONE_FIELD_OPTION = typer.Option(
    None, "--field", help="Normalized field, 0..1 of the lens's maximum field along +y (one field; default 0, on axis)."
)
ONE_FIELD_DEG_OPTION = typer.Option(None, "--field-deg", help="The field as an object-space angle (deg, below 90).")
ONE_IMAGE_HEIGHT_OPTION = typer.Option(
    None, "--image-height-mm", help="The field as the real chief ray's image height (mm)."
)
CURVES_FIELD_HELP = FIELD_HELP.replace("Default: the lens's own fields.", "Default: 21 fields from 0 to the maximum.")
CURVES_FIELD_OPTION = typer.Option(None, "--field", help=CURVES_FIELD_HELP)


def _outputs(output: Path | None, json_out: bool) -> None:
    if output is None and not json_out:
        raise InputError(None, "--output", "expected -o FILE (a figure to write), --json, or both")
    if output is not None:
        _check_figure_name(output)


def _fields(lens: Lens, field, field_deg, image_height_mm) -> tuple[Lens, list[float]]:
    """The lens to trace and the fields to show, in its unit (default: its own fields)."""
    from lensim.optics.analysis import fields_to_show

    shown, values = fields_to_show(lens, field, field_deg, image_height_mm)
    return shown, list(shown.fields) if values is None else values


def _spectrum(
    lens: Lens, sensor: str | None, channel: str | None, wavelengths: str | None
) -> tuple[list[float], list[float], float | None]:
    """(wavelengths um, weights, sensor Nyquist frequency lp/mm or None)."""
    from lensim.psf.bank.settings import parse_wavelengths_nm

    if channel is not None and sensor is None:
        raise InputError(None, "--channel", "applies with --sensor only")
    nm = (
        None
        if wavelengths is None
        else [wavelength_nm(w, "--wavelengths-nm") for w in parse_wavelengths_nm(wavelengths)]
    )
    if sensor is None:
        if nm is None:
            return list(lens.wavelengths_um), [float(w) for w in lens.wavelength_weights or []], None
        return [w / 1000.0 for w in nm], [1.0] * len(nm), None
    from lensim.sensor.profile import load_sensor
    from lensim.sensor.spectral import CHANNELS as SENSOR_CHANNELS
    from lensim.sensor.spectral import spectral_response

    profile = load_sensor(sensor)
    nm = list(parse_wavelengths_nm(DEFAULT_WAVELENGTHS_TEXT)) if nm is None else nm
    weights = spectral_response(nm, profile.spectral_response).weights
    ch = channel or "all"
    w = weights.sum(0) if ch == "all" else weights[SENSOR_CHANNELS.index(ch)]
    return [v / 1000.0 for v in nm], [float(v) for v in w], 1000.0 / (2.0 * profile.pixel_pitch_um)


def _settings(fno, object_m, focus_m, config, focus_mode) -> tuple[str | None, ...]:
    return (fno, object_m, focus_m, config, focus_mode)


@lens_app.command("mtf")
def mtf_command(
    lens_file: str = LENS_ARG,
    output: Path | None = typer.Option(None, "-o", "--output", help=OUTPUT_HELP),
    json_out: bool = typer.Option(False, "--json", help="Print the MTF curves as JSON."),
    field: list[float] | None = FIELD_OPTION,
    field_deg: list[float] | None = FIELD_DEG_OPTION,
    image_height_mm: list[float] | None = IMAGE_HEIGHT_OPTION,
    frequency: list[float] | None = typer.Option(
        None,
        "--frequency",
        help="Frequency (lp/mm) of the MTF-against-field and through-focus curves; repeat for several. "
        "Default: Nyquist/4 and /2 of --sensor, else 10 and 30.",
    ),
    max_frequency: float | None = typer.Option(
        None,
        "--max-frequency",
        help="Top of the frequency axis (lp/mm). Default: the sensor's Nyquist, else the cutoff.",
    ),
    sensor: str | None = typer.Option(None, "--sensor", help=SENSOR_HELP),
    channel: str | None = typer.Option(None, "--channel", help=CHANNEL_HELP),
    wavelengths: str | None = typer.Option(None, "--wavelengths-nm", help=WAVELENGTHS_HELP),
    sweep_fields: int = typer.Option(
        21, "--sweep-fields", help="Fields of the MTF-against-field curves (0 to the maximum)."
    ),
    focus_range_um: float | None = typer.Option(
        None,
        "--focus-range-um",
        help="Through-focus half-range (um). Default: 4 lambda N^2 (twice the depth of focus).",
    ),
    focus_steps: int = typer.Option(11, "--focus-steps", help="Through-focus image-plane positions (0: none)."),
    pupil_samples: int = typer.Option(64, "--pupil-samples", help=PUPIL_HELP),
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """Diffraction MTF (FFT: pupil autocorrelation), sagittal and tangential: against
    frequency at each field, against the field (--sweep-fields points from 0 to the maximum) at the
    chosen frequencies, and through focus; polychromatic with the lens file's weights or
    the sensor's spectral response; lateral colour included.

    Example: lensim lens mtf cooke_triplet --sensor apsc_mirrorless -o mtf.png --json
    """
    from lensim.optics.paraxial import paraxial_data
    from lensim.plots.analysis import mtf_figure
    from lensim.psf.analysis_reports import mtf_report

    _outputs(output, json_out)
    for f in frequency or []:
        positive(f, "--frequency", "lp/mm", "a frequency")
    if max_frequency is not None:
        positive(max_frequency, "--max-frequency", "lp/mm", "a frequency")
    if focus_range_um is not None:
        positive(focus_range_um, "--focus-range-um", "um", "a focus range")
    at_least(focus_steps, 0, "--focus-steps", what="a number of focus positions")
    in_range(sweep_fields, 2, 1001, "--sweep-fields", what="a number of fields")
    at_least(pupil_samples, 16, "--pupil-samples", what="a number of pupil samples")
    if channel is not None:
        choice(channel, CHANNELS, "--channel")
    base, _ = _load(lens_file, shooting=_settings(fno, object_m, focus_m, config, focus_mode))
    lens, fields = _fields(base, field, field_deg, image_height_mm)
    wls, weights, nyquist = _spectrum(lens, sensor, channel, wavelengths)
    freqs = frequency or ([nyquist / 4.0, nyquist / 2.0] if nyquist else [10.0, 30.0])
    steps = []
    if focus_steps:
        para = paraxial_data(lens)
        mean_wl = sum(w * x for w, x in zip(weights, wls, strict=True)) / sum(weights)
        half = (focus_range_um or 4.0 * mean_wl * para.working_fno**2) * 1e-3
        steps = [(-half + 2.0 * half * k / (focus_steps - 1)) if focus_steps > 1 else 0.0 for k in range(focus_steps)]
    with progress_bar("MTF", "steps", quiet or json_out) as cb:
        report = mtf_report(
            lens,
            fields,
            wls,
            weights,
            freqs,
            _sweep(base, lens, sweep_fields),
            steps,
            max_frequency or nyquist,
            samples=pupil_samples,
            aiming=aiming.value,
            progress=cb,
        )
    report["nyquist_lp_mm"] = nyquist
    report["weighting"] = f"sensor {sensor} ({channel or 'all'})" if sensor else "lens file"
    _finish(report, output, json_out, lambda: mtf_figure(report, output))


def _sweep(base: Lens, lens: Lens, count: int) -> list[float]:
    """The MTF-against-field sweep, count fields from 0: to the lens file's maximum field,
    or to the largest field shown when they are given in another unit (--field-deg,
    --image-height-mm)."""
    top = base.max_field if lens.field_type == base.field_type else lens.max_field
    return [top * k / (count - 1) for k in range(count)]


def _finish(report: dict, output: Path | None, json_out: bool, draw) -> None:
    if output is not None:
        draw()
        report["output"] = str(output)
    if json_out:
        print_json(report)
    else:
        console.print(f"wrote {output}", highlight=False)


@lens_app.command("wavefront")
def wavefront_command(
    lens_file: str = LENS_ARG,
    output: Path | None = typer.Option(None, "-o", "--output", help=OUTPUT_HELP),
    json_out: bool = typer.Option(
        False, "--json", help="Print RMS, PV, Strehl (piston and tilt removed) and the Zernike coefficients as JSON."
    ),
    field: list[float] | None = ONE_FIELD_OPTION,
    field_deg: list[float] | None = ONE_FIELD_DEG_OPTION,
    image_height_mm: list[float] | None = ONE_IMAGE_HEIGHT_OPTION,
    wavelength: float | None = typer.Option(None, "--wavelength-nm", help="Wavelength in nm (default: the primary)."),
    zernike: str = typer.Option(
        "noll",
        "--zernike",
        help="Zernike convention: noll (standard: Noll order, RMS-normalized) or fringe "
        "(University of Arizona, 37 terms).",
    ),
    zernike_terms: int = typer.Option(
        37, "--zernike-terms", help="Zernike terms to fit (noll up to 231, fringe up to 37)."
    ),
    pupil_samples: int = typer.Option(64, "--pupil-samples", help=PUPIL_HELP),
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming."),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """The wavefront of one field (default on axis): OPD against the reference sphere
    (centred on the real chief-ray image point, through the exit pupil), RMS and PV,
    Strehl from the wavefront, and its Zernike coefficients (waves).

    Example: lensim lens wavefront cooke_triplet --field 0.7 --zernike fringe -o wavefront.png --json
    """
    from lensim.plots.analysis import wavefront_figure
    from lensim.psf.analysis_reports import wavefront_report

    _outputs(output, json_out)
    choice(zernike, ZERNIKE_CONVENTIONS, "--zernike")
    top = ZERNIKE_MAX_TERMS[zernike]
    in_range(zernike_terms, 1, top, "--zernike-terms", what=f"a number of {zernike} terms")
    at_least(pupil_samples, 16, "--pupil-samples", what="a number of pupil samples")
    if wavelength is not None:
        wavelength_nm(wavelength)
    lens, _ = _load(lens_file, shooting=_settings(fno, object_m, focus_m, config, focus_mode))
    if not (field or field_deg or image_height_mm):
        field = [0.0]
    lens, fields = _fields(lens, field, field_deg, image_height_mm)
    if len(fields) != 1:
        raise InputError(None, "--field", f"expected one field, got {len(fields)}")
    wl = lens.primary_wavelength_um if wavelength is None else wavelength / 1000.0
    report, opd = wavefront_report(lens, fields[0], wl, zernike, zernike_terms, pupil_samples, aiming.value)
    _finish(report, output, json_out, lambda: wavefront_figure(report, opd, output))


@lens_app.command("fans")
def fans_command(
    lens_file: str = LENS_ARG,
    output: Path | None = typer.Option(None, "-o", "--output", help=OUTPUT_HELP),
    json_out: bool = typer.Option(False, "--json", help="Print the fans (um, per field and wavelength) as JSON."),
    field: list[float] | None = FIELD_OPTION,
    field_deg: list[float] | None = FIELD_DEG_OPTION,
    image_height_mm: list[float] | None = IMAGE_HEIGHT_OPTION,
    rays: int = typer.Option(41, "--rays", help="Rays per fan, from pupil -1 to 1."),
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming."),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """Transverse ray aberration fans: ey of the tangential fan against py and ex of the
    sagittal fan against px, every wavelength, relative to the primary chief ray (um).

    Example: lensim lens fans cooke_triplet --field 0 --field 0.7 --field 1 -o fans.png --json
    """
    from lensim.optics.fans import ray_fans
    from lensim.plots.analysis import fans_figure

    _outputs(output, json_out)
    in_range(rays, 3, 1001, "--rays", what="a number of rays")
    lens, _ = _load(lens_file, shooting=_settings(fno, object_m, focus_m, config, focus_mode))
    lens, fields = _fields(lens, field, field_deg, image_height_mm)
    report = {"name": lens.name, "source": lens.source} | ray_fans(lens, fields, rays, aiming.value).to_dict()
    _finish(report, output, json_out, lambda: fans_figure(report, output))


@lens_app.command("field-curves")
def field_curves_command(
    lens_file: str = LENS_ARG,
    output: Path | None = typer.Option(None, "-o", "--output", help=OUTPUT_HELP),
    json_out: bool = typer.Option(False, "--json", help="Print the foci per field and wavelength (mm) as JSON."),
    field: list[float] | None = CURVES_FIELD_OPTION,
    field_deg: list[float] | None = FIELD_DEG_OPTION,
    image_height_mm: list[float] | None = IMAGE_HEIGHT_OPTION,
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming."),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """Field curvature: the tangential and sagittal foci of the chief ray's neighbourhood
    (parabasal ray pairs) against the field, each wavelength, as distances from the image
    plane (mm, positive away from the lens); astigmatism T - S.

    Example: lensim lens field-curves cooke_triplet -o field_curves.png --json
    """
    from lensim.optics.analysis import fields_to_show
    from lensim.optics.fans import field_curves
    from lensim.plots.analysis import field_curves_figure

    _outputs(output, json_out)
    lens, _ = _load(lens_file, shooting=_settings(fno, object_m, focus_m, config, focus_mode))
    lens, fields = fields_to_show(lens, field, field_deg, image_height_mm)
    report = {"name": lens.name, "source": lens.source} | field_curves(lens, fields, aiming.value).to_dict()
    _finish(report, output, json_out, lambda: field_curves_figure(report, output))


@lens_app.command("energy")
def energy_command(
    lens_file: str = LENS_ARG,
    output: Path | None = typer.Option(None, "-o", "--output", help=OUTPUT_HELP),
    json_out: bool = typer.Option(False, "--json", help="Print the curves and the EE50/80/90 sizes as JSON."),
    field: list[float] | None = FIELD_OPTION,
    field_deg: list[float] | None = FIELD_DEG_OPTION,
    image_height_mm: list[float] | None = IMAGE_HEIGHT_OPTION,
    sensor: str | None = typer.Option(None, "--sensor", help=SENSOR_HELP.split(" and its pixel")[0] + "."),
    channel: str | None = typer.Option(None, "--channel", help=CHANNEL_HELP),
    wavelengths: str | None = typer.Option(None, "--wavelengths-nm", help=WAVELENGTHS_HELP),
    method: str = typer.Option("huygens", "--method", help=f"PSF method: one of {', '.join(METHODS)}."),
    centre: str = typer.Option("centroid", "--centre", help="Centre of the circles and squares: centroid or chief."),
    grid: int = typer.Option(128, "--grid", help="PSF window size in samples (grid x grid)."),
    spacing_um: float | None = typer.Option(
        None, "--spacing-um", help="PSF sample spacing in um (default: lambda_min N / 4)."
    ),
    pupil_samples: int | None = typer.Option(
        None, "--pupil-samples", help="Pupil grid samples across the diameter (default: what the window needs, >= 64)."
    ),
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress output."),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """Encircled and ensquared energy against radius and half-width per field, from the
    polychromatic PSF (Huygens by default), as fractions of the transmitted energy.

    Example: lensim lens energy cooke_triplet --field 0 --field 1 -o energy.png --json
    """
    from lensim.plots.analysis import energy_figure
    from lensim.psf.analysis_reports import energy_report

    _outputs(output, json_out)
    kind = psf_method(method, "--method", None)
    choice(centre, ("centroid", "chief"), "--centre")
    if channel is not None:
        choice(channel, CHANNELS, "--channel")
    in_range(grid, 16, 1024, "--grid", "samples", "a PSF window")
    if spacing_um is not None:
        positive(spacing_um, "--spacing-um", "um", "a sample spacing")
    if pupil_samples is not None:
        at_least(pupil_samples, 16, "--pupil-samples", what="a number of pupil samples")
    lens, _ = _load(lens_file, shooting=_settings(fno, object_m, focus_m, config, focus_mode))
    lens, fields = _fields(lens, field, field_deg, image_height_mm)
    wls, weights, _ = _spectrum(lens, sensor, channel, wavelengths)
    with progress_bar("encircled energy", "fields", quiet or json_out) as cb:
        report = energy_report(
            lens, fields, wls, weights, grid, spacing_um, pupil_samples, aiming.value, kind, centre, progress=cb
        )
    _finish(report, output, json_out, lambda: energy_figure(report, output))
