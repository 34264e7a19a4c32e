"""`lensim export`: a trained restoration network as an ONNX model (lensim.restore.export)."""

from __future__ import annotations

from pathlib import Path

import typer

from lensim.cli.common import console, print_json
from lensim.cli.validate import output_file
from lensim.errors import InputError


def export_command(
    run: Path = typer.Argument(..., help="Run folder (best.pt, else last.pt) or checkpoint file of `lensim train`."),
    output: Path = typer.Option(..., "-o", "--output", help="ONNX file to write (.onnx)."),
    opset: int = typer.Option(17, "--opset", help="ONNX opset (17 or newer, up to what this PyTorch writes)."),
    quiet: bool = typer.Option(False, "--quiet", help="No output."),
    json_out: bool = typer.Option(False, "--json", help="Print the file written and its metadata as JSON."),
) -> None:
    """Export a trained restoration network to ONNX: named inputs rgb (N, 3, H, W) sRGB in
    [0, 1], fov (N, 2, H, W) field-of-view channels (and settings when conditioned), output
    restored; dynamic batch, height and width. The file's metadata records the sensor, lens,
    FOV convention and training settings; `lensim restore FILE.onnx ... --engine
    onnxruntime` runs it with the usual tiling.

    Example: lensim export runs/model -o model.onnx
    """
    from lensim.restore.export import check_opset, export_onnx, read_metadata

    check_opset(opset)
    output_file(output, "--output", suffixes=(".onnx",))
    if not run.exists():
        raise InputError(str(run), None, "no such run folder or checkpoint file")
    path = export_onnx(run, output, opset=opset)
    meta = read_metadata(path)
    if json_out:
        print_json({"output": str(path), "bytes": path.stat().st_size, "metadata": meta})
    elif not quiet:
        console.print(
            f"exported {meta['checkpoint']['path']} -> {path} (opset {opset}, {meta['arch']}, "
            f"size multiple {meta['size_multiple']})",
            highlight=False,
        )


__all__ = ["export_command"]
