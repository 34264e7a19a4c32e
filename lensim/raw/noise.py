"""Raw noise parameters from calibration frames (photon transfer).

The sensor model (lensim.sensor.profile): a pixel of mean normalized signal x has variance
``shot * x + read**2``. A dark frame (lens cap on, same ISO) gives ``read``: the spread of
its pixels about their local mean. Flat fields (an evenly lit, defocused surface) give the
photon transfer curve: each small tile of one CFA colour has a mean and a variance, and
the variance grows linearly with the mean, slope ``shot``, intercept ``read**2``. Tiles
(8x8 same-colour pixels) keep lens shading and the slow illumination gradient out of the
variance; saturated tiles are left out.
"""

from __future__ import annotations

import numpy as np

from lensim.errors import InputError, ParameterError
from lensim.raw.read import RawImage

TILE = 8  # same-colour pixels per tile side
SATURATION = 0.98  # normalized level above which a tile counts as clipped


def _tile_stats(frame: RawImage) -> tuple[np.ndarray, np.ndarray]:
    """(means, variances) of every TILE x TILE tile of each CFA plane, normalized units."""
    from lensim.raw.develop import normalized_mosaic

    x = normalized_mosaic(frame).double().numpy()
    means, variances = [], []
    for dy, dx in ((0, 0), (0, 1), (1, 0), (1, 1)):
        plane = x[dy::2, dx::2]
        th, tw = plane.shape[0] // TILE, plane.shape[1] // TILE
        tiles = (
            plane[: th * TILE, : tw * TILE].reshape(th, TILE, tw, TILE).transpose(0, 2, 1, 3).reshape(-1, TILE * TILE)
        )
        keep = tiles.max(axis=1) < SATURATION
        means.append(tiles[keep].mean(axis=1))
        variances.append(tiles[keep].var(axis=1, ddof=1))
    return np.concatenate(means), np.concatenate(variances)


def _check_frame(raw: RawImage, frame: RawImage, what: str) -> None:
    if (frame.width, frame.height, frame.cfa_pattern) != (raw.width, raw.height, raw.cfa_pattern):
        raise InputError(
            frame.path,
            what,
            f"found a {frame.width}x{frame.height} {frame.cfa_pattern} frame; expected "
            f"the camera of {raw.path} ({raw.width}x{raw.height} {raw.cfa_pattern})",
        )


def read_noise(dark: RawImage) -> float:
    """Read noise (standard deviation, normalized units) of a dark frame."""
    _, variances = _tile_stats(dark)
    if variances.size == 0:
        raise InputError(dark.path, "dark frame", "has no unsaturated area of 16x16 pixels")
    return float(np.sqrt(np.mean(variances)))


def photon_transfer(flats: list[RawImage], read: float | None = None) -> tuple[float, float]:
    """(shot, read) from flat fields: least squares of tile variance on tile mean, with the
    intercept fixed at ``read**2`` when the read noise is known (from a dark frame). Without
    it the flats must span mean levels at least 2x apart (two exposures)."""
    stats = [_tile_stats(f) for f in flats]
    means = np.concatenate([m for m, _ in stats])
    variances = np.concatenate([v for _, v in stats])
    src = flats[0].path
    if means.size < 2 or not means.max() > 0:
        raise InputError(src, "flat field", "has no usable (lit, unsaturated) tiles")
    if read is not None:
        shot = float(np.sum(means * (variances - read**2)) / np.sum(means**2))
    else:
        if not means.max() >= 2.0 * max(means.min(), 1e-12):
            raise InputError(
                src,
                "flat field",
                "one exposure level cannot separate shot from read noise; give a "
                "dark frame (`dark`) or flats at two exposures",
            )
        shot, read_sq = np.polyfit(means, variances, 1)
        read = float(np.sqrt(max(read_sq, 0.0)))
        shot = float(shot)
    if not shot > 0:
        raise InputError(
            src,
            "flat field",
            f"variance does not grow with the signal (slope {shot:.3g}); expected an evenly lit, unsaturated frame",
        )
    return shot, float(read)


def noise_from_frames(
    raw: RawImage,
    dark: RawImage | None = None,
    flats: list[RawImage] | None = None,
) -> dict[str, float] | None:
    """The profile's noise mapping {shot, read} from calibration frames of the camera that
    wrote ``raw`` (None without frames; read noise alone needs a flat for the shot noise)."""
    flats = flats or []
    for frame, what in [(dark, "dark frame")] + [(f, "flat field") for f in flats]:
        if frame is not None:
            _check_frame(raw, frame, what)
    if dark is None and not flats:
        return None
    if not flats:
        raise ParameterError(None, "dark", "a dark frame gives the read noise only; give a flat field (`flats`) too")
    read = read_noise(dark) if dark is not None else None
    shot, read = photon_transfer(flats, read)
    return {"shot": shot, "read": read}
