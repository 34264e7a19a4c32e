"""The demo report: sample crops, slanted-edge and lateral-colour studies, and a
self-contained HTML page (images embedded) beside report.json."""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from lensim.data.pairs import crop_capture
from lensim.evaluate.harness import CropContext, Method, markdown_table
from lensim.images import read_image
from lensim.io import atomic_write_text
from lensim.jsonable import jsonable
from lensim.psf.bank import PSFBank
from lensim.render.mapping import native_mapping
from lensim.render.pipeline import simulate
from lensim.sensor.profile import SensorProfile


def _figure(size: tuple[float, float]):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> Path:
    from lensim.plots import save_figure

    save_figure(fig, path)
    return path


def _context(
    manifest: Mapping[str, Any], rec: Mapping[str, Any], k: int, sensor: SensorProfile, bank: PSFBank
) -> tuple[CropContext, int]:
    crop = rec["crops"][k]
    size = int(manifest["size"])
    m = native_mapping(size, size, sensor, int(crop["sensor_top"]), int(crop["sensor_left"]))
    return CropContext(
        m,
        sensor,
        bank,
        crop_capture(rec, crop),
        int(crop["sensor_top"]),
        int(crop["sensor_left"]),
        int(rec["index"]),
        k,
    ), size


def sample_crops(
    pairs_dir: Path, manifest: Mapping[str, Any], held_out: list[str], model: Method, bank: PSFBank, figs: Path
) -> list[dict]:
    """Before / after / ground-truth strips of the held-out crops nearest the centre and
    nearest the edge of the sensor; returns their positions and file names."""
    from lensim.sensor.profile import sensor_from_dict

    sensor = sensor_from_dict(manifest["sensor"], "manifest")
    keep = set(held_out)
    cands = []
    for rec in manifest["records"]:
        if Path(rec["source"]).name not in keep and rec["source"] not in keep:
            continue
        for k, c in enumerate(rec["crops"]):
            size = int(manifest["size"])
            dy = c["sensor_top"] + size / 2 - sensor.height / 2
            dx = c["sensor_left"] + size / 2 - sensor.width / 2
            cands.append((math.hypot(dx, dy) / math.hypot(sensor.width / 2, sensor.height / 2), rec, k))
    if not cands:
        return []
    cands.sort(key=lambda t: t[0])
    out = []
    for label, (r, rec, k) in (("centre", cands[0]), ("edge", cands[-1])):
        ctx, _ = _context(manifest, rec, k, sensor, bank)
        x, _ = read_image(pairs_dir / rec["crops"][k]["input"])
        y, _ = read_image(pairs_dir / rec["crops"][k]["target"])
        with torch.no_grad():
            z = model(x, ctx).clamp(0, 1)
        fig = _figure((9, 3.3))
        for i, (img, title) in enumerate(((x, "camera (simulated)"), (z, "restored"), (y, "ground truth"))):
            ax = fig.add_subplot(1, 3, i + 1)
            ax.imshow(img.permute(1, 2, 0).numpy(), interpolation="nearest")
            ax.set_title(title)
            ax.axis("off")
        fig.suptitle(f"{label}: sensor radius {r:.2f} (1 = corner)")
        fig.tight_layout()
        name = f"crops_{label}.png"
        _save(fig, figs / name)
        out.append({"zone": label, "sensor_radius": r, "figure": name})
    return out


def edge_study(
    bank: PSFBank,
    sensor: SensorProfile,
    model: Method,
    figs: Path,
    seed: int = 0,
    fields: tuple[float, ...] = (0.0, 0.5, 0.9),
    size: int = 96,
) -> dict:
    """A sharp slanted edge (5 deg) imaged by the simulated camera without noise at several
    fields, then restored: MTF50 and MTF area (to Nyquist) of the green channel, and the
    R-G / B-G edge shifts (px), before and after."""
    from lensim.evaluate.chromatic import lateral_color_edge
    from lensim.evaluate.edge_target import make_slanted_edge
    from lensim.evaluate.slanted_edge import slanted_edge_mtf

    r_max = float(bank.radii_mm[-1])
    p = sensor.pixel_pitch_um * 1e-3
    rows_mtf, rows_lc = [], []
    fig = _figure((4.2 * len(fields), 3.4))
    for i, f in enumerate(fields):
        # the crop's centre at radius f * r_max along +x (a tangential edge)
        cx = sensor.width / 2 + f * r_max / p * min(1.0, (sensor.width / 2 - size) / (r_max / p))
        left = int(round(cx - size / 2)) // 2 * 2
        top = (sensor.height // 2 - size // 2) // 2 * 2
        edge = torch.from_numpy(make_slanted_edge(size, 5.0, 0.15, 0.85)).float()
        sharp = edge.unsqueeze(0).repeat(3, 1, 1)
        m = native_mapping(size, size, sensor, top, left)
        cam, params = simulate(
            sharp, bank, sensor, torch.Generator().manual_seed(seed), noise=False, kelvin=5500.0, mapping=m
        )
        ctx = CropContext(m, sensor, bank, params.to_dict(), top, left, -1, i)
        with torch.no_grad():
            restored = model(cam, ctx).clamp(0, 1)
        field_here = math.hypot(left + size / 2 - sensor.width / 2, top + size / 2 - sensor.height / 2) * p / r_max
        ax = fig.add_subplot(1, len(fields), i + 1)
        entry_m: dict[str, Any] = {"normalized_field": field_here}
        entry_c: dict[str, Any] = {"normalized_field": field_here}
        for name, img, style in (("before", cam, "--"), ("after", restored, "-"), ("sharp", sharp, ":")):
            region = img[:, 8:-8, 8:-8].numpy()
            g = slanted_edge_mtf(region[1])
            entry_m[name] = {"mtf50_cy_px": float(g.mtf50), "mtf_area": float(g.area_to_nyquist)}
            ax.plot(g.freq_cy_px, g.mtf, style, label=name)
            if name != "sharp":
                lc = lateral_color_edge(region.transpose(1, 2, 0))
                entry_c[name] = {"r_minus_g_px": lc.r_minus_g_px, "b_minus_g_px": lc.b_minus_g_px}
        ax.set_xlim(0, 0.5)
        ax.set_ylim(0, max(1.05, ax.get_ylim()[1]))
        ax.set_xlabel("cycles / pixel")
        ax.set_title(f"field {field_here:.2f}")
        ax.grid(alpha=0.3)
        if i == 0:
            ax.set_ylabel("MTF (green)")
            ax.legend()
        rows_mtf.append(entry_m)
        rows_lc.append(entry_c)
    fig.tight_layout()
    _save(fig, figs / "slanted_edge.png")
    return {"slanted_edge": rows_mtf, "lateral_colour": rows_lc}


def raw_file_figure(dng: Path, restored: Path, truth: torch.Tensor, sensor: SensorProfile, figs: Path) -> dict:
    """The demo's raw file side by side: the DNG developed by `lensim develop`'s chain, the
    TIFF `lensim restore` wrote for it, the sharp photo; PSNR (dB) of the first two
    against the truth. Writes figs/raw_file.png; returns the report's raw_file figures."""
    from lensim.evaluate.metrics import psnr
    from lensim.raw import read_raw
    from lensim.raw.develop import develop_raw

    developed, _ = develop_raw(read_raw(dng), sensor, bits=None, orient=False)
    out, _ = read_image(restored)
    scores = {
        "developed_psnr_db": psnr(developed.numpy(), truth.numpy()),
        "restored_psnr_db": psnr(out.numpy(), truth.numpy()),
    }
    fig = _figure((9, 3.3))
    for i, (img, title) in enumerate(
        (
            (developed, f"raw file, developed ({scores['developed_psnr_db']:.2f} dB)"),
            (out, f"restored ({scores['restored_psnr_db']:.2f} dB)"),
            (truth, "ground truth"),
        )
    ):
        ax = fig.add_subplot(1, 3, i + 1)
        ax.imshow(img.clamp(0, 1).permute(1, 2, 0).numpy(), interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    _save(fig, figs / "raw_file.png")
    return {**scores, "figure": "raw_file.png"}


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(path.name)}">'


def _metrics_html(metrics: Mapping[str, Any]) -> str:
    rows = ["<tr><th>method</th><th>PSNR (dB)</th><th>SSIM</th><th>centre</th><th>middle</th><th>edge</th></tr>"]
    for name, m in metrics["methods"].items():
        z = m["zones"]

        def f(v, d=2):
            return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{d}f}"

        rows.append(
            f"<tr><td>{html.escape(name)}</td><td>{f(m['psnr_db'])}</td><td>{f(m['ssim'], 3)}</td>"
            f"<td>{f(z['centre']['psnr_db'])}</td><td>{f(z['middle']['psnr_db'])}</td>"
            f"<td>{f(z['edge']['psnr_db'])}</td></tr>"
        )
    return "<table>" + "".join(rows) + "</table>"


def _networks_html(training: Mapping[str, Any] | None) -> str:
    """What the report's trained methods are: the demo's network and the plain network (its
    architecture as report.json's training entries name it, when they do)."""
    if not isinstance(training, Mapping):
        return ""

    def named(key: str) -> str:
        entry = training.get(key)
        network = entry.get("network") if isinstance(entry, Mapping) else None
        return f" ({html.escape(str(network))})" if network else ""

    text = f" <code>model</code> is the demo's network{named('model')}."
    model = training.get("model")
    if isinstance(model, Mapping) and model.get("init") == "universal":
        text = (
            f" <code>model</code> is the demo's network{named('model')}, fine-tuned from the shipped universal "
            "model on this lens's pairs; <code>universal</code> is that universal model zero-shot: pretrained on "
            "a library of other lenses, never trained on this one, given this lens's PSF bank."
        )
    if "plain" in training:
        text += (
            f" <code>plain</code> is the plain network{named('plain')}: no field-aware part (FOV channels, "
            "deformable blocks, context block), about the size of the demo's network, trained on the same "
            "time budget."
        )
    return text


def _raw_file_html(raw: Mapping[str, Any] | None) -> str:
    if not raw:
        return "<p>(not run)</p>"
    return (
        f"<p>The held-out photo <code>{html.escape(raw['photo'])}</code> simulated at the sensor's right edge "
        f"(top-left sensor pixel {raw['sensor_top']}, {raw['sensor_left']}) and written as a CFA DNG "
        f"(<code>{html.escape(raw['dng'])}</code>, as <code>lensim simulate</code> writes a raw output), then "
        "restored by <code>lensim restore</code>'s raw path: developed with the simulator's chain (no "
        "sharpening), restored with the field of view of its place on the sensor. PSNR against the truth: "
        f"developed {raw['developed_psnr_db']:.2f} dB, restored {raw['restored_psnr_db']:.2f} dB.</p>"
    )


def write_report(out: Path, report: dict, figs: Path) -> Path:
    """report.json (every figure of the report), report.html (self-contained) and
    figures/metrics.md. The page and the table are rendered before anything is written,
    so a report lacking a figure raises (KeyError, TypeError) with the files untouched."""
    page = _report_page(report, figs)
    table = markdown_table(report["metrics"])
    atomic_write_text(out / "report.json", json.dumps(jsonable(report), indent=1, default=str) + "\n")
    atomic_write_text(out / "report.html", page)
    atomic_write_text(figs / "metrics.md", table)
    return out / "report.html"


def _report_page(report: dict, figs: Path) -> str:
    """The self-contained HTML page of a report (figures from ``figs`` inlined)."""
    lens = report["lens"]
    sections = [
        (
            "Lens",
            f"<p>{html.escape(lens['name'])}: EFL {lens['efl_mm']:.2f} mm, F/{lens['fno']:.2f}, image height "
            f"{lens['image_height_mm']:.2f} mm. Sensor: {html.escape(report['sensor']['name'])}.</p>",
            ["layout.png", "spots.png"],
        ),
        (
            "Point spread functions",
            "<p>Huygens PSFs over the sensor (RGB kernels, gamma-stretched), Strehl ratio "
            "and MTF against field, relative illumination.</p>",
            ["psf_map.png", "strehl.png", "mtf.png", "relative_illumination.png"],
        ),
        (
            "Restoration on held-out photos",
            _metrics_html(report["metrics"])
            + "<p>PSNR / SSIM against the sharp originals; zones by normalized sensor radius (centre &lt; 1/3, "
            "middle, edge &ge; 2/3 of the half-diagonal). <code>input</code> is the simulated camera image; <code>wiener</code> is an oracle "
            f"given the true PSFs.{_networks_html(report.get('training'))}</p>",
            ["crops_centre.png", "crops_edge.png"],
        ),
        ("A camera raw file", _raw_file_html(report.get("raw_file")), ["raw_file.png"]),
        (
            "Slanted edge and lateral colour",
            "<pre>"
            + html.escape(
                json.dumps(
                    jsonable({"slanted_edge": report["slanted_edge"], "lateral_colour": report["lateral_colour"]}),
                    indent=1,
                )
            )
            + "</pre>",
            ["slanted_edge.png"],
        ),
    ]
    body = []
    for title, text, images in sections:
        imgs = "".join(_img(figs / n) for n in images if (figs / n).exists())
        body.append(f"<section><h2>{html.escape(title)}</h2>{text}<div class='figs'>{imgs}</div></section>")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>lensim report</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em}}
img{{max-width:100%;margin:0.5em 0;display:block}} table{{border-collapse:collapse}}
td,th{{border:1px solid #bbb;padding:0.25em 0.6em;text-align:right}} pre{{font-size:0.8em}}</style></head>
<body><h1>lensim report</h1>
<p>Optical aberration simulation and correction after Chen et al., "Optical aberrations correction in
postprocessing using imaging simulation", ACM TOG 2021. Settings: {html.escape(json.dumps(report["settings"]))}.</p>
{"".join(body)}
<p>Timings (s): {html.escape(json.dumps({k: round(v, 1) for k, v in report["timings_s"].items()}))}</p>
</body></html>
"""
    return page
