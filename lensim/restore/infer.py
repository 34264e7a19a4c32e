"""Inference: tiled restoration of images of any size (checkpoints: lensim.restore.checkpoint).

Engines: the tiling is the one home for every engine. :func:`restore_image` takes the
PyTorch network (wrapped in :class:`TorchEngine`) or any :class:`Engine`, such as the
onnxruntime session of an exported model (lensim.restore.engines.OnnxEngine); an engine
only restores one tile given its RGB, FOV channels and optional settings vector.

Tiling (:func:`restore_image`): the image is cut into a grid of tiles of at most ``tile``
pixels a side whose top-left corners lie at multiples of ``model.size_multiple`` (the
network is shift-equivariant only for such shifts; see lensim.restore.network). Each tile
is fed the FOV channels of its *absolute* sensor position (fov_channels at the image's
sensor offset plus the tile's offset), so a tile sees exactly what the whole image would
show it. Neighbouring tiles overlap by at least ``overlap`` pixels. In an overlap, each
tile's blending weight is 0 over the ``margin`` pixels next to its inner edge (context
only: these outputs miss part of their receptive field), rises linearly to 1 over the
remaining overlap - 2 * margin pixels, and is 1 beyond; the weights are separable
(w_y(r) * w_x(c)) and normalised to sum to 1 at every pixel, so no (H, W) weight buffer is
needed. Tile edges on the image border get weight 1 up to the border (the whole-image pass
pads there exactly as a border tile does). When ``margin`` exceeds the receptive-field
radius (about 58 px for the paper's UNet with zero offsets, plus what learned offsets
add) the result equals whole-image inference up to float rounding.

Memory: the input, the (3, H, W) float32 output and one tile's activations. A tile the
memory cannot hold (an allocation fails: lensim.errors.out_of_memory) makes
:func:`restore_image` start again with tiles of half the side, as long as they stay larger
than the overlap, with a warning; below that an OutOfMemory names the tile. Measured on
CPU: a 512-pixel tile of the paper's UNet peaks at about 1.3 GB (the full-resolution
deformable conv lays its 9 samples out as a (C, 3H, 3W) image), a width-8 network at about
0.4 GB; a 24-megapixel image takes 0.29 GB each for input and output. Smaller tiles cut
the tile term (roughly with the tile area) at the cost of more overlap work. Each axis's
tiles are made as small as their count allows (:func:`even_tile`), so the overlap is spread
evenly. A 24 MP frame computes 1.21 times its pixels in NAFNet's tiles (up to 1024 px,
overlap 96: :func:`default_tile`, :func:`default_overlap`; about 0.5 GB for a tile of the
width-46 stem-2 network), 1.5 times in tiles of 512 px at that overlap, and 2.5 times
at the UNet's defaults (512 px, overlap 192).

Sensor mapping (:func:`image_sensor_geometry`): a photo is assumed to be a full sensor
frame mapped like lensim.render.mapping.map_to_sensor (fitted inside the sensor, centred, the
limiting side spanning it) unless an explicit offset of its top-left pixel on the sensor
is given (then it is at the sensor's native pixel scale, like lensim.render.mapping.native_mapping).
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import torch

from lensim.errors import OutOfMemory, out_of_memory
from lensim.restore.conditioning import batch_settings
from lensim.restore.fov import fov_channels

#: `lensim restore`'s tiling defaults (pixels); DEFAULT_OVERLAP is for a network that names
#: no overlap of its own (the paper's UNet: margin 72 px > its 58 px receptive field)
DEFAULT_TILE = 512
DEFAULT_OVERLAP = 192


def default_overlap(model: object) -> int:
    """The tile overlap (pixels) restore_image uses for a network or engine by default: its
    ``tile_overlap`` when it names one (NAFNet and the PSF-informed network: 96, see
    lensim.restore.nafnet; an exported model: the overlap its metadata records), else
    DEFAULT_OVERLAP."""
    return int(getattr(model, "tile_overlap", None) or DEFAULT_OVERLAP)


def default_tile(model: object) -> int:
    """The largest tile side (pixels) restore_image uses for a network or engine by default:
    its ``tile_size`` when it names one (NAFNet's plain layouts and the PSF-informed
    network: 1024, see lensim.restore.nafnet; an exported model: the tile its metadata
    records), else DEFAULT_TILE."""
    return int(getattr(model, "tile_size", None) or DEFAULT_TILE)


#: The arithmetic of a PyTorch network's tiles (restore_image's ``precision``): "float32";
#: "bfloat16" (PyTorch's autocast: convolutions in bfloat16, the operations between them
#: in their inputs' dtype, the network's final sum with its float32 input image in
#: float32); "auto": bfloat16 on a CPU that computes it natively
#: (AVX512-BF16 or AMX), else float32. Measured (benchmarks/restore_precision.py): on an
#: AVX512-BF16 CPU a width-46 tile runs 1.4-2.4x faster in bfloat16 (a whole 24 MP photo
#: 1.35x), its output 65 dB PSNR from float32's.
PRECISIONS = ("auto", "float32", "bfloat16")


def native_bfloat16(device: torch.device | str = "cpu") -> bool:
    """Whether ``device`` computes bfloat16 convolutions natively: a CPU with AVX512-BF16 or
    AMX tiles (oneDNN), or a CUDA GPU that supports bfloat16."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    cpu = torch.cpu
    return bool(cpu._is_avx512_bf16_supported() or cpu._is_amx_tile_supported())  # type: ignore[attr-defined]


def tile_dtype(precision: str, engine: object) -> torch.dtype | None:
    """The autocast dtype of an engine's tiles at ``precision`` (:data:`PRECISIONS`), None
    for float32. "auto" picks bfloat16 only for a PyTorch network on a CPU that computes it
    natively (on a GPU the measured gain was 1.09x: float32). bfloat16 applies to PyTorch
    networks only; ValueError for another engine or an unknown precision."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if isinstance(engine, torch.nn.Module):
        engine = TorchEngine(engine)  # its parameters' device, which a bare module does not name
    torch_network = isinstance(engine, TorchEngine)
    device = torch.device(getattr(engine, "device", "cpu"))
    if precision == "float32" or (precision == "auto" and not (torch_network and device.type == "cpu")):
        return None
    if not torch_network:
        raise ValueError(f"precision bfloat16 applies to a PyTorch network; {type(engine).__name__} runs float32")
    if precision == "auto":
        return torch.bfloat16 if native_bfloat16(device) else None
    return torch.bfloat16


def _autocast(device: torch.device, dtype: torch.dtype | None) -> contextlib.AbstractContextManager[object]:
    return contextlib.nullcontext() if dtype is None else torch.autocast(device.type, dtype=dtype)


def default_margin(overlap: int) -> int:
    """The context-only margin restore_image uses by default: (overlap - overlap // 4) // 2
    pixels, i.e. a linear ramp over the middle quarter of the overlap."""
    return (overlap - overlap // 4) // 2


# ----------------------------------------------------------------------------- engines


@runtime_checkable
class Engine(Protocol):
    """What restore_image runs tiles with: a PyTorch network (:class:`TorchEngine`) or an
    exported ONNX model (lensim.restore.engines.OnnxEngine).

    Attributes: size_multiple (tiles start at multiples of it), use_fov (whether the FOV
    channels are fed), settings_dim (D, the length of the settings vector; 0: none),
    device and dtype (where and in what restore_image builds a tile's inputs). Calling it
    with rgb (1, 3, h, w), fov (1, 2, h, w) or None and settings (1, D) or None returns
    the restored tile (1, 3, h, w) (any device and float dtype)."""

    size_multiple: int
    use_fov: bool
    settings_dim: int
    device: torch.device
    dtype: torch.dtype

    def __call__(
        self, rgb: torch.Tensor, fov: torch.Tensor | None, settings: torch.Tensor | None = None
    ) -> torch.Tensor: ...


class TorchEngine:
    """A PyTorch network as an :class:`Engine`: tiles are built on its parameters' device
    and in their dtype (so CUDA and half-precision networks run as they are). uses_wiener:
    the network takes the Wiener stage's image (lensim.restore.psfnet)."""

    def __init__(self, model: torch.nn.Module) -> None:
        param = next(model.parameters())
        self.model = model
        self.uses_wiener = bool(getattr(model, "uses_wiener", False))
        self.size_multiple = int(getattr(model, "size_multiple", 1))
        self.use_fov = bool(getattr(model, "use_fov", True))
        self.settings_dim = int(getattr(model, "settings_dim", 0) or 0)
        self.tile_overlap = default_overlap(model)
        self.tile_size = default_tile(model)
        self.device = param.device
        self.dtype = param.dtype

    def __call__(
        self,
        rgb: torch.Tensor,
        fov: torch.Tensor | None,
        settings: torch.Tensor | None = None,
        wiener: torch.Tensor | None = None,
    ) -> torch.Tensor:
        if self.uses_wiener:
            return self.model(rgb, fov, settings, wiener)
        if settings is None:
            return self.model(rgb, fov)
        return self.model(rgb, fov, settings)


def as_engine(model: torch.nn.Module | Engine) -> Engine:
    """``model`` itself when it is an Engine, else the network wrapped in a TorchEngine."""
    if isinstance(model, torch.nn.Module):
        return TorchEngine(model)
    if isinstance(model, Engine):
        return model
    raise TypeError(f"expected a torch.nn.Module or an Engine, got {type(model).__name__}")


# ----------------------------------------------------------------------------- geometry


def image_sensor_geometry(
    height: int,
    width: int,
    sensor_resolution: tuple[int, int],
    offset: tuple[int | float, int | float] | None = None,
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Sensor geometry of an image, in the image's own pixel units, for fov_channels.

    Args:
        height, width: image size in pixels.
        sensor_resolution: (width, height) of the sensor in pixels (square pixels).
        offset: (top, left) sensor pixel of the image's top-left pixel at native scale, or
            None for a full frame fitted like lensim.render.mapping.map_to_sensor.

    Returns:
        ((top, left), (sensor_height, sensor_width)) in image pixels: the image's top-left
        corner relative to the sensor's and the sensor size (floats when scaled).
    """
    sw, sh = float(sensor_resolution[0]), float(sensor_resolution[1])
    if offset is not None:
        return (float(offset[0]), float(offset[1])), (sh, sw)
    scale = min(sw / width, sh / height)  # sensor pixels per image pixel
    hs, ws = sh / scale, sw / scale
    return ((hs - height) / 2.0, (ws - width) / 2.0), (hs, ws)


def tile_starts(length: int, tile: int, overlap: int, multiple: int) -> list[int]:
    """Start offsets (multiples of ``multiple``) of tiles of size ``tile`` covering
    [0, length), consecutive tiles overlapping by at least ``overlap`` pixels; the last
    tile ends at ``length`` (and may be shorter than ``tile``)."""
    if length <= tile:
        return [0]
    step = max(multiple, (tile - overlap) // multiple * multiple)
    last = -(-(length - tile) // multiple) * multiple  # ceil to a multiple
    starts = [0]
    while starts[-1] + tile < length:
        starts.append(min(starts[-1] + step, last))
    return starts


def even_tile(length: int, tile: int, overlap: int, multiple: int) -> int:
    """The tile side (pixels, a multiple of ``multiple``, at most ``tile``) that covers
    [0, length) with as few tiles as ``tile`` does but spreads them evenly: the smallest
    such side, so the tiles overlap about as little as ``overlap`` allows instead of the
    last one overlapping its neighbour by nearly a whole tile. For a 6000 x 4000 frame in
    tiles of 512 px with 96 px of overlap: 492 x 488 px instead of 512 x 512, 1.50 instead
    of 1.64 times the frame's pixels computed."""
    tile = max(multiple, tile // multiple * multiple)
    count = len(tile_starts(length, tile, overlap, multiple))
    if count == 1:
        return tile
    side = -(-(length + (count - 1) * overlap) // count)  # count tiles, overlapping by exactly `overlap`
    side = max(overlap + multiple, -(-side // multiple) * multiple)
    while side < tile and len(tile_starts(length, side, overlap, multiple)) > count:
        side += multiple
    return min(side, tile)


def _axis_weights(length: int, starts: list[int], tile: int, overlap: int, margin: int) -> list[torch.Tensor]:
    """Per-tile 1-D blending weights along one axis, normalised to sum to 1 per pixel."""
    ramp = overlap - 2 * margin
    ws = []
    for s in starts:
        e = min(s + tile, length)
        x = torch.arange(s, e, dtype=torch.float64) + 0.5
        w = torch.ones(e - s, dtype=torch.float64)
        if s > 0:
            w = torch.minimum(w, ((x - s - margin) / ramp).clamp(0, 1))
        if e < length:
            w = torch.minimum(w, ((e - margin - x) / ramp).clamp(0, 1))
        ws.append(w)
    total = torch.zeros(length, dtype=torch.float64)
    for s, w in zip(starts, ws):
        total[s : s + len(w)] += w
    if bool((total <= 0).any()):
        raise ValueError(
            f"tiles do not cover every pixel with positive weight (tile {tile}, overlap {overlap}, margin {margin})"
        )
    return [(w / total[s : s + len(w)]).to(torch.float32) for s, w in zip(starts, ws)]


# ----------------------------------------------------------------------------- restore


def smaller_tile(tile: int, overlap: int, multiple: int) -> int | None:
    """The next tile side to try after ``tile`` ran out of memory: half of it (a multiple
    of ``multiple``), or None when that would not exceed the overlap."""
    half = (tile // 2) // multiple * multiple
    return half if half > overlap and half >= multiple else None


@torch.no_grad()
def restore_image(
    model: torch.nn.Module | Engine,
    image: torch.Tensor,
    sensor_top_left: tuple[float, float],
    sensor_size: tuple[float, float],
    tile: int | None = None,
    overlap: int | None = None,
    margin: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    settings: torch.Tensor | None = None,
    wiener: torch.Tensor | None = None,
    precision: str = "float32",
) -> torch.Tensor:
    """Restore a (3, H, W) image of any size, tile by tile (see the module docstring).

    Args:
        model: the network, any architecture of lensim.restore.models (its device and dtype
            are used for the tiles), or any :class:`Engine` (an exported ONNX model:
            lensim.restore.engines).
        image: (3, H, W) float in [0, 1] (any device; the output is on the CPU).
        sensor_top_left: (top, left) of the image's top-left pixel on the sensor, in image
            pixels (image_sensor_geometry).
        sensor_size: (height, width) of the sensor in image pixels.
        tile: largest tile side in pixels (rounded down to a multiple of model.size_multiple;
            None: the network's, :func:`default_tile`); each axis's tiles are then made as
            small as their count allows (:func:`even_tile`); halved while a tile runs out of
            memory (smaller_tile; a UserWarning says so).
        overlap: least overlap of neighbouring tiles in pixels (< tile); None: the
            network's (:func:`default_overlap`).
        margin: pixels next to an inner tile edge given weight 0 (default
            (overlap - overlap // 4) // 2, i.e. a linear ramp over the middle quarter).
        progress: called with (tiles done, tiles total).
        settings: (k,) settings vector of the photo for a network conditioned on shooting
            settings (Conditioning.vector; model.settings_dim = k), given to every tile;
            None for an unconditioned network.
        wiener: (3, H, W) the Wiener stage's image of the whole image, for a network that
            takes it (``uses_wiener``: lensim.restore.psfnet; computed by
            lensim.restore.psf_stage.photo_wiener); each tile gets its part.
        precision: the tiles' arithmetic for a PyTorch network (:data:`PRECISIONS`,
            :func:`tile_dtype`); the output is float32 either way.

    Returns:
        (3, H, W) float32 restored image on the CPU (not clamped).

    Raises:
        lensim.errors.OutOfMemory (field "tile") when even the smallest tile the overlap
        allows runs out of memory.
    """
    if image.dim() != 3 or image.shape[0] != 3:
        raise ValueError(f"image must be (3, H, W), got {tuple(image.shape)}")
    engine = as_engine(model)
    if bool(getattr(engine, "uses_wiener", False)) != (wiener is not None):
        raise ValueError(
            "the network takes the Wiener stage's image (lensim.restore.psf_stage.photo_wiener); give wiener"
            if wiener is None
            else "wiener was given but the network does not take it"
        )
    if wiener is not None and tuple(wiener.shape) != tuple(image.shape):
        raise ValueError(f"wiener must have the image's shape {tuple(image.shape)}, got {tuple(wiener.shape)}")
    m = engine.size_multiple
    tile = max(m, (default_tile(engine) if tile is None else tile) // m * m)
    if overlap is None:
        overlap = default_overlap(engine)
    if not 0 <= overlap < tile:
        raise ValueError(f"overlap must be in [0, tile={tile}), got {overlap}")
    if margin is None:
        margin = default_margin(overlap)
    if overlap - 2 * margin < 1 and overlap > 0:
        raise ValueError(f"overlap ({overlap}) must exceed 2 * margin ({margin})")
    overlap_eff = max(overlap, 2 * margin + 1)
    autocast = _autocast(engine.device, tile_dtype(precision, engine))
    out = torch.zeros(3, *image.shape[1:], dtype=torch.float32)
    while True:
        try:
            with autocast:
                return _restore_tiles(
                    engine,
                    (image, wiener),
                    out,
                    (sensor_top_left, sensor_size),
                    (tile, overlap_eff, margin),
                    progress,
                    settings,
                )
        except Exception as e:  # noqa: BLE001  (PyTorch's and onnxruntime's allocation failures)
            if not out_of_memory(e):
                raise
            smaller = smaller_tile(tile, overlap_eff, m)
            if smaller is None:
                raise OutOfMemory(
                    None,
                    "tile",
                    f"not enough memory for tiles of {tile} pixels, the smallest that an overlap of "
                    f"{overlap_eff} pixels allows",
                ) from None
            warnings.warn(
                f"not enough memory for tiles of {tile} pixels; restoring with tiles of {smaller} pixels",
                UserWarning,
                stacklevel=2,
            )
            tile = smaller
            out.zero_()


def _restore_tiles(
    engine: Engine,
    images: tuple[torch.Tensor, torch.Tensor | None],
    out: torch.Tensor,
    geometry: tuple[tuple[float, float], tuple[float, float]],
    tiling: tuple[int, int, int],
    progress: Callable[[int, int], None] | None,
    settings: torch.Tensor | None,
) -> torch.Tensor:
    """restore_image's pass over its tiles, accumulated into ``out`` (zeros, (3, H, W));
    images: (the image, its Wiener stage image or None); geometry: (sensor top-left,
    sensor size); tiling: (tile, overlap, margin)."""
    image, wiener = images
    top, left = (float(v) for v in geometry[0])
    sh, sw = (float(v) for v in geometry[1])
    tile, overlap, margin = tiling
    m = engine.size_multiple
    _, h, w = image.shape
    tile_h, tile_w = even_tile(h, tile, overlap, m), even_tile(w, tile, overlap, m)
    ys = tile_starts(h, tile_h, overlap, m)
    xs = tile_starts(w, tile_w, overlap, m)
    wy = _axis_weights(h, ys, tile_h, overlap, margin)
    wx = _axis_weights(w, xs, tile_w, overlap, margin)
    total, done = len(ys) * len(xs), 0
    device, dtype = engine.device, engine.dtype
    vec = batch_settings(settings, 1, engine.settings_dim, torch.empty(0, device=device, dtype=dtype))
    for y0, wyy in zip(ys, wy):
        th = len(wyy)
        for x0, wxx in zip(xs, wx):
            tw = len(wxx)
            rgb = image[:, y0 : y0 + th, x0 : x0 + tw].to(device=device, dtype=dtype).unsqueeze(0)
            fov = None
            if engine.use_fov:
                fov = fov_channels(th, tw, top + y0, left + x0, sh, sw, dtype=dtype, device=device).unsqueeze(0)
            if wiener is None:
                res = engine(rgb, fov, vec)[0].float().cpu()
            else:
                part = wiener[:, y0 : y0 + th, x0 : x0 + tw].to(device=device, dtype=dtype).unsqueeze(0)
                res = engine(rgb, fov, vec, part)[0].float().cpu()  # type: ignore[call-arg]
            out[:, y0 : y0 + th, x0 : x0 + tw] += res * (wyy.view(1, th, 1) * wxx.view(1, 1, tw))
            done += 1
            if progress is not None:
                progress(done, total)
    return out


__all__ = [
    "DEFAULT_OVERLAP",
    "DEFAULT_TILE",
    "Engine",
    "PRECISIONS",
    "TorchEngine",
    "as_engine",
    "default_margin",
    "even_tile",
    "image_sensor_geometry",
    "native_bfloat16",
    "restore_image",
    "smaller_tile",
    "tile_dtype",
    "tile_starts",
]
