"""`lensim lens ...`: inspect, plot and convert lens prescriptions."""

from __future__ import annotations

import math
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.table import Table

from lensim.cli.bank_options import (
    config_option,
    fno_option,
    focus_m_option,
    focus_mode_option,
    object_m_option,
    shooting_settings,
)
from lensim.cli.common import console, print_json
from lensim.cli.validate import AIMINGS, choice, output_file
from lensim.errors import InputError
from lensim.optics.aiming.modes import Aiming

if TYPE_CHECKING:
    from lensim.optics.lens import Lens

lens_app = typer.Typer(help="Inspect, plot and convert lens prescriptions.", no_args_is_help=True)

LENS_ARG = typer.Argument(..., help="Lens file (.json/.yaml native, .zmx Zemax, .seq CODE V) or a built-in lens name.")


MATCH_GLASS_HELP = (
    "Replace each model glass (nd/Vd) by the nearest catalogue glass (smallest RMS index "
    "difference over 400-700 nm); lens info reports each replacement."
)
MODEL_GLASS_HELP = (
    "Keep each bare nd/Vd pair (a patent's glass) a model glass on Schott's normal line, where by default "
    "a pair that matches a catalogue glass within its rounding is that glass (with its partial dispersion)."
)
GLASS_MAKERS_HELP = (
    "Catalogues --match-glass searches, comma-separated (Schott, Ohara, CDGM, Hikari, Hoya, Sumita). Default: all."
)


def _glass_makers(makers: str | None, match_glass: bool) -> list[str] | None:
    """The --glass-makers list (lensim.optics.materials.glass_makers), checked before any
    work; it needs --match-glass."""
    from lensim.optics.materials import glass_makers

    if makers is None:
        return None
    if not match_glass:
        raise InputError(None, "--glass-makers", "only applies with --match-glass")
    return glass_makers(makers)


def _model_glass(model_glass: bool, match_glass: bool) -> bool:
    """--model-glass, refused beside --match-glass (which replaces every model glass)."""
    if model_glass and match_glass:
        raise InputError(None, "--model-glass", "cannot be combined with --match-glass; expected one of them")
    return model_glass


def _load(
    lens_file: str,
    match_glass: bool = False,
    makers: list[str] | None = None,
    shooting: tuple[str | None, ...] = (None, None, None, None),
    model_glass: bool = False,
):
    """Load a lens (model_glass: its bare nd/Vd pairs stay model glasses, see load_lens);
    with match_glass its model glasses become the nearest catalogue glasses; then it is set
    to the shooting options (--fno, --object-m, --focus-m, --config). Returns (lens, glass
    matches)."""
    lens, matches, _ = _load_set(lens_file, match_glass, makers, shooting, model_glass)
    return lens, matches


def _load_set(
    lens_file: str,
    match_glass: bool = False,
    makers: list[str] | None = None,
    shooting: tuple[str | None, ...] = (None, None, None, None),
    model_glass: bool = False,
):
    """_load, and the shooting settings resolved as records keep them (None when none is
    given)."""
    from lensim.optics.lens_file import load_lens, match_glasses
    from lensim.optics.shooting import lens_and_record

    settings = shooting_settings(*shooting)
    # --match-glass replaces every model glass by its nearest catalogue glass, as it always did
    lens = load_lens(lens_file, model_glasses=model_glass or match_glass)
    matches: list[dict] = []
    if match_glass:
        lens, matches = match_glasses(lens, makers)
    lens, described = lens_and_record(lens, settings)
    return lens, matches, described


def _fmt(x, digits=6) -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "inf"
    return f"{x:.{digits}g}"


@lens_app.command("info")
def info(
    lens_file: str = LENS_ARG,
    json_out: bool = typer.Option(False, "--json", help="Print a JSON object instead of tables."),
    aiming: str = typer.Option("real", help="Ray aiming for real-ray figures: real or paraxial."),
    match_glass: bool = typer.Option(False, "--match-glass", help=MATCH_GLASS_HELP),
    model_glass: bool = typer.Option(False, "--model-glass", help=MODEL_GLASS_HELP),
    glass_makers: str | None = typer.Option(None, "--glass-makers", help=GLASS_MAKERS_HELP),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """Surface table and first-order data (EFL, BFL, F/#, pupils, fields, wavelengths), of
    the lens at the shooting options when given.

    Example: lensim lens info phone_wide --match-glass --glass-makers Ohara,Schott --json
    """
    from lensim.optics.analysis import first_order_summary

    choice(aiming, AIMINGS, "--aiming")
    lens, matches, described = _load_set(
        lens_file,
        match_glass,
        _glass_makers(glass_makers, match_glass),
        (fno, object_m, focus_m, config, focus_mode),
        _model_glass(model_glass, match_glass),
    )
    summary = first_order_summary(lens, aiming=aiming)
    if described is not None:
        summary["settings"] = described
    if json_out:
        print_json(summary | {"glass_matches": matches} if match_glass else summary)
        return
    console.print(_surface_table(lens))
    f = Table(title="First-order data", show_header=False)
    f.add_column("quantity")
    f.add_column("value", justify="right")
    rows = [
        ("EFL", f"{summary['efl_mm']:.6g} mm"),
        ("BFL", f"{summary['bfl_mm']:.6g} mm"),
        ("F/# (image space)", f"{summary['fno']:.5g}"),
        ("working F/#", f"{summary['working_fno']:.5g}"),
        ("entrance pupil diameter", f"{summary['epd_mm']:.6g} mm"),
        ("entrance pupil z", f"{summary['entrance_pupil_z_mm']:.6g} mm"),
        ("exit pupil z", f"{summary['exit_pupil_z_mm']:.6g} mm"),
        ("exit pupil diameter", f"{summary['exit_pupil_diameter_mm']:.6g} mm"),
        ("total track", f"{summary['total_track_mm']:.6g} mm"),
        (
            "object distance",
            "infinity" if summary["object_distance_mm"] is None else f"{summary['object_distance_mm']:.6g} mm",
        ),
        ("fields", f"{', '.join(f'{v:g}' for v in lens.fields)} ({lens.field_type}, {summary['field_unit']})"),
        (
            "wavelengths",
            ", ".join(f"{w * 1000:.1f}{'*' if i == lens.primary else ''}" for i, w in enumerate(lens.wavelengths_um))
            + " nm (* primary)",
        ),
        ("real image height (max field)", f"{summary['image_height_mm']:.6g} mm"),
    ]
    for k, v in rows:
        f.add_row(k, v)
    console.print(f)
    if described is not None:
        console.print("settings: " + ", ".join(f"{k} {v}" for k, v in described.items()), highlight=False)
    for note in lens.notes:
        console.print(f"note: {note}", highlight=False)


def _surface_table(lens: Lens) -> Table:
    """lens info's surface table: radii, thicknesses, clear semi-diameters in mm, nd at the d line."""
    from lensim.optics.materials import Air

    t = Table(title=f"{lens.name or Path(lens.source).name}  (lengths in mm)")
    for col in ("#", "radius", "thickness", "material", "nd", "conic", "clear s.d.", "note"):
        t.add_column(col, justify="right" if col not in ("material", "note") else "left")
    nd_wl = 0.5875618
    for i, s in enumerate(lens.surfaces):
        mat = "MIRROR" if s.is_mirror else ("" if isinstance(s.material, Air) else s.material.name)
        nd = "" if isinstance(s.material, Air) or s.is_mirror else f"{s.material.index(nd_wl).item():.5f}"
        note = ", ".join(
            x
            for x in (
                "STOP" if s.is_stop else "",
                s.kind if s.is_aspheric else "",
                f"obsc {s.obscuration_radius:g}" if s.obscuration_radius else "",
            )
            if x
        )
        t.add_row(
            str(i + 1),
            _fmt(s.radius),
            _fmt(s.thickness),
            mat,
            nd,
            _fmt(s.conic) if s.conic else "",
            _fmt(s.clear_radius) if s.clear_radius is not None else "",
            note,
        )
    return t


@lens_app.command("convert")
def convert(
    lens_file: str = LENS_ARG,
    output: Path = typer.Option(..., "-o", "--output", help="Native lens file to write (.json or .yaml)."),
    match_glass: bool = typer.Option(False, "--match-glass", help=MATCH_GLASS_HELP),
    model_glass: bool = typer.Option(False, "--model-glass", help=MODEL_GLASS_HELP),
    glass_makers: str | None = typer.Option(None, "--glass-makers", help=GLASS_MAKERS_HELP),
) -> None:
    """Convert any supported lens file to lensim's native format.

    Example: lensim lens convert design.zmx -o design.yaml
    """
    from lensim.optics.lens_file import save_lens

    makers = _glass_makers(glass_makers, match_glass)
    if output.suffix.lower() not in (".json", ".yaml", ".yml"):
        raise InputError(str(output), "--output", "expected a .json, .yaml or .yml file name for a native lens file")
    output_file(output)
    lens, _ = _load(lens_file, match_glass, makers, model_glass=_model_glass(model_glass, match_glass))
    save_lens(lens, output)
    console.print(f"wrote {output}", highlight=False)


class AimingChoice(str, Enum):
    """Ray aiming: through the paraxial entrance pupil, or iterated onto the real stop."""

    real = "real"
    paraxial = "paraxial"


class ReferenceChoice(str, Enum):
    """The point spot diagrams are centred on and RMS radii are measured from."""

    chief = "chief"
    centroid = "centroid"


class PlotKind(str, Enum):
    """What `lens plot` draws."""

    layout = "layout"
    distortion = "distortion"
    lateral_colour = "lateral-colour"
    illumination = "illumination"


SENSOR_HELP = (
    "Sensor profile (file or built-in name) whose spectral response weights the lateral colour "
    "of its R, G, B channels. Default: the default sensor's."
)


def _check_figure_name(output: Path) -> None:
    """A one-line error for an image name matplotlib cannot write or a place it cannot
    be written to, before any work."""
    from lensim.plots.figure import new_figure

    fmt = output.suffix[1:].lower()
    if fmt not in new_figure((1, 1)).canvas.get_supported_filetypes():
        raise InputError(str(output), "--output", "expected an image name ending in .png, .pdf or .svg")
    output_file(output)


def _channel_weights(sensor: str | None):
    """(wavelengths_nm, (3, W) channel weights) of the sensor's spectral response."""
    from lensim.sensor.profile import load_sensor
    from lensim.sensor.spectral import spectral_response

    resp = spectral_response(None, load_sensor(sensor).spectral_response)
    return resp.wavelengths_nm, resp.weights


def _field_report(lens: Lens, fields: list[float] | None, sensor: str | None, aiming: AimingChoice) -> dict:
    from lensim.optics.field_analysis import field_report

    wavelengths_nm, weights = _channel_weights(sensor)
    aim: Aiming = "real" if aiming is AimingChoice.real else "paraxial"
    return field_report(lens, fields, wavelengths_nm, weights, aiming=aim)


FIELD_HELP = (
    "Normalized field to show, 0..1 of the lens's maximum field along +y; repeat for several. "
    "Default: the lens's own fields."
)
FIELD_DEG_HELP = "Field to show as an object-space angle (deg, below 90); repeat for several."
IMAGE_HEIGHT_HELP = "Field to show as the real chief ray's image height (mm); repeat for several."


@lens_app.command("plot")
def plot(
    lens_file: str = LENS_ARG,
    output: Path = typer.Option(..., "-o", "--output", help="Image to write (.png, .pdf or .svg)."),
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming for the ray fans."),
    rays: int = typer.Option(7, "--rays", min=1, max=101, help="Meridional rays per field, spread across the pupil."),
    field: list[float] | None = typer.Option(None, "--field", help=FIELD_HELP),
    field_deg: list[float] | None = typer.Option(None, "--field-deg", help=FIELD_DEG_HELP),
    image_height_mm: list[float] | None = typer.Option(None, "--image-height-mm", help=IMAGE_HEIGHT_HELP),
    kind: PlotKind = typer.Option(
        PlotKind.layout,
        "--kind",
        help="layout (ray fans), or against the field: "
        "distortion (%), lateral-colour (um per sensor channel) or illumination.",
    ),
    sensor: str | None = typer.Option(None, "--sensor", help=SENSOR_HELP),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """Draw the lens layout (a y-z cross-section with a fan of rays per field), or its
    distortion, lateral colour or relative illumination against the field.

    Layout: lengths in mm, primary wavelength; vignetted rays end where they are blocked.
    The field curves use the fields given (default 21 from the axis to the maximum field).

    Example: lensim lens plot cooke_triplet -o layout.png --rays 9 --field 0 --field 0.7 --field 1
    Example: lensim lens plot cooke_triplet --kind lateral-colour --sensor apsc_mirrorless -o lateral.png
    """
    from lensim.optics.analysis import fields_to_show

    _check_figure_name(output)
    lens, _ = _load(lens_file, shooting=(fno, object_m, focus_m, config, focus_mode))
    lens, fields = fields_to_show(lens, field, field_deg, image_height_mm)
    if kind is PlotKind.layout:
        from lensim.plots.lens import plot_layout

        if sensor is not None:
            raise InputError(None, "--sensor", "applies to --kind lateral-colour (and the other field curves) only")
        plot_layout(lens, fields=fields, rays_per_field=rays, aiming=aiming.value, path=output)
    else:
        from lensim.plots.field import field_figure

        field_figure(_field_report(lens, fields, sensor, aiming), kind.value, output)
    console.print(f"wrote {output}", highlight=False)


@lens_app.command("spot")
def spot(
    lens_file: str = LENS_ARG,
    output: Path | None = typer.Option(
        None, "-o", "--output", help="Spot-diagram image to write (.png, .pdf or .svg)."
    ),
    aiming: AimingChoice = typer.Option(AimingChoice.paraxial, help="Ray aiming."),
    json_out: bool = typer.Option(
        False,
        "--json",
        help="Print, per field and wavelength, the RMS spot radius (um) "
        "and the chief-ray position on the image plane (mm) as JSON.",
    ),
    field: list[float] | None = typer.Option(None, "--field", help=FIELD_HELP),
    field_deg: list[float] | None = typer.Option(None, "--field-deg", help=FIELD_DEG_HELP),
    image_height_mm: list[float] | None = typer.Option(None, "--image-height-mm", help=IMAGE_HEIGHT_HELP),
    reference: ReferenceChoice = typer.Option(
        ReferenceChoice.chief, help="Centre of the spots and of the RMS radius: the chief ray or the centroid."
    ),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """Spot diagrams and RMS spot radii for each field, all wavelengths.

    Give -o to draw them (axes in um, Airy disk dashed), --json to print the numbers, or both.

    Example: lensim lens spot cooke_triplet -o spot.png --json --image-height-mm 0 --image-height-mm 14.1
    """
    from lensim.optics.aiming.sampling import hexapolar
    from lensim.optics.analysis import fields_to_show
    from lensim.optics.spot import SPOT_RINGS, spot_diagram, spot_report

    if output is None and not json_out:
        raise InputError(None, "--output", "expected -o FILE (an image to write), --json, or both")
    if output is not None:
        _check_figure_name(output)
    lens, _ = _load(lens_file, shooting=(fno, object_m, focus_m, config, focus_mode))
    lens, fields = fields_to_show(lens, field, field_deg, image_height_mm)
    spots = spot_diagram(lens, fields, None, hexapolar(SPOT_RINGS), aiming.value)
    if output is not None:
        from lensim.plots.lens import plot_spots

        plot_spots(lens, aiming=aiming.value, path=output, reference=reference.value, spots=spots)
    if json_out:
        report = spot_report(lens, spots, aiming.value, reference.value)
        per_field = report.pop("fields")
        print_json({**report, "output": None if output is None else str(output), "fields": per_field})
    else:
        console.print(f"wrote {output}", highlight=False)


@lens_app.command("field")
def field_command(
    lens_file: str = LENS_ARG,
    json_out: bool = typer.Option(False, "--json", help="Print the per-field records as JSON instead of a table."),
    sensor: str | None = typer.Option(None, "--sensor", help=SENSOR_HELP),
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming of the chief rays."),
    field: list[float] | None = typer.Option(
        None,
        "--field",
        help=FIELD_HELP.replace("Default: the lens's own fields.", "Default: 21 fields from the axis to the maximum."),
    ),
    field_deg: list[float] | None = typer.Option(None, "--field-deg", help=FIELD_DEG_HELP),
    image_height_mm: list[float] | None = typer.Option(None, "--image-height-mm", help=IMAGE_HEIGHT_HELP),
    match_glass: bool = typer.Option(False, "--match-glass", help=MATCH_GLASS_HELP),
    model_glass: bool = typer.Option(False, "--model-glass", help=MODEL_GLASS_HELP),
    glass_makers: str | None = typer.Option(None, "--glass-makers", help=GLASS_MAKERS_HELP),
    fno: str | None = fno_option(),
    object_m: str | None = object_m_option(),
    focus_m: str | None = focus_m_option(),
    focus_mode: str | None = focus_mode_option(),
    config: str | None = config_option(),
) -> None:
    """Lens-level outputs per field: the real chief-ray height at each wavelength, the
    paraxial height, distortion (%), lateral colour of each sensor channel (its chief-ray
    height weighted by the sensor's spectral response, minus green's, um) and relative
    illumination. With --match-glass, of the lens with catalogue glasses for its model glasses.

    Example: lensim lens field cooke_triplet --sensor apsc_mirrorless --json
    """
    from lensim.optics.analysis import fields_to_show

    lens, matches = _load(
        lens_file,
        match_glass,
        _glass_makers(glass_makers, match_glass),
        (fno, object_m, focus_m, config, focus_mode),
        _model_glass(model_glass, match_glass),
    )
    lens, fields = fields_to_show(lens, field, field_deg, image_height_mm)
    report = _field_report(lens, fields, sensor, aiming)
    if json_out:
        print_json(report | {"glass_matches": matches} if match_glass else report)
        return
    unit = report["field_unit"]
    t = Table(title=f"{lens.name or Path(lens.source).name}: field outputs (heights in mm, lateral colour in um)")
    for col in (f"field ({unit})", "real y", "paraxial y", "distortion %", "R - G", "B - G", "rel. illum."):
        t.add_column(col, justify="right")
    for r in report["fields"]:
        t.add_row(
            f"{r['field']:.4g}",
            f"{r['channel_height_mm']['g']:.5f}",
            f"{r['paraxial_height_mm']:.5f}",
            f"{r['distortion_percent']:+.4f}",
            f"{r['lateral_colour_um']['r']:+.3f}",
            f"{r['lateral_colour_um']['b']:+.3f}",
            f"{r['relative_illumination']:.4f}",
        )
    console.print(t)
    if matches:  # match_glasses added one note per replaced surface, last
        for note in lens.notes[-len(matches) :]:
            console.print(f"note: {note}", highlight=False)


@lens_app.command("lensfun")
def lensfun_command(
    lens_file: str = LENS_ARG,
    maker: str = typer.Option(..., "--maker", help="Lens maker as lensfun shows it."),
    model: str = typer.Option(..., "--model", help="Lens model name."),
    mount: str = typer.Option(..., "--mount", help="Lens mount, as lensfun names it (e.g. 'Sony E', 'Generic')."),
    crop_factor: float = typer.Option(
        ...,
        "--crop-factor",
        help="Crop factor of the frame the profile is for (full frame 1; the lens must cover the 3:2 frame's corner).",
    ),
    focal: float = typer.Option(..., "--focal", help="Focal length (mm) the profile is filed under."),
    aperture: float = typer.Option(..., "--aperture", help="F-number: the lens is evaluated stopped to it."),
    distance: float | None = typer.Option(
        None,
        "--distance",
        help="Focus distance (m from the image plane, as "
        "cameras report it): the lens is refocused there. "
        "Default: the lens file's object distance.",
    ),
    output: Path = typer.Option(..., "-o", "--output", help="lensfun database file to write (.xml)."),
    sensor: str | None = typer.Option(None, "--sensor", help=SENSOR_HELP),
    aiming: AimingChoice = typer.Option(AimingChoice.real, help="Ray aiming of the chief rays."),
    match_glass: bool = typer.Option(False, "--match-glass", help=MATCH_GLASS_HELP),
    model_glass: bool = typer.Option(False, "--model-glass", help=MODEL_GLASS_HELP),
    glass_makers: str | None = typer.Option(None, "--glass-makers", help=GLASS_MAKERS_HELP),
) -> None:
    """Write a lensfun profile of the lens (for darktable, RawTherapee, Hugin): ptlens
    distortion, poly3 lateral colour (from the sensor-channel-weighted chief rays) and pa
    vignetting (from the relative illumination), fitted from the axis to the corner of a
    3:2 frame at the crop factor.

    Example: lensim lens lensfun cooke_triplet --maker lensim --model "Cooke triplet 50mm" --mount Generic
    --crop-factor 1.5 --focal 50 --aperture 5.6 -o cooke.xml
    """
    from lensim.optics.lensfun import check_settings, lensfun_profile, write_profile

    check_settings(maker, model, mount, crop_factor, focal, aperture, distance)
    if output.suffix.lower() != ".xml":
        raise InputError(str(output), "--output", "expected a .xml file name (a lensfun database file)")
    output_file(output)
    lens, _ = _load(
        lens_file,
        match_glass,
        _glass_makers(glass_makers, match_glass),
        model_glass=_model_glass(model_glass, match_glass),
    )
    wavelengths_nm, weights = _channel_weights(sensor)
    profile = lensfun_profile(
        lens,
        maker,
        model,
        mount,
        crop_factor,
        focal,
        aperture,
        wavelengths_nm,
        weights,
        distance_m=distance,
        aiming=aiming.value,
    )
    write_profile(profile, output)
    fit = profile.fit
    console.print(
        f"wrote {output} (largest fit residuals: distortion {fit['distortion_um']:.3g} um, "
        f"lateral colour {fit['tca_um']:.3g} um, vignetting {fit['vignetting']:.2g})",
        highlight=False,
    )
