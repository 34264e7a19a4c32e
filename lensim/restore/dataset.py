"""A torch Dataset over a pairs folder written by ``lensim dataset make`` (lensim.data.pairs).

Layout read: DATASET/manifest.json (lensim.data.manifest.read_pairs_manifest) with
``sensor.resolution`` = [width, height] (pixels), ``records[i].source`` (the sharp photo)
and ``records[i].crops[k]`` = {input, target, sensor_top, sensor_left}: paths relative to
DATASET of the aberrated and sharp crops, and the absolute sensor pixel of the crop's
top-left corner.

Every item is a dict
    input  (3, h, w) float32 in [0, 1]  aberrated crop
    target (3, h, w) float32 in [0, 1]  sharp crop
    fov    (2, h, w) float32            FOV channels of the crop's absolute sensor pixels
                                        (lensim.restore.fov.fov_channels), after augmentation
    index  int                          the item's index in this dataset
    settings (k,) float32               the settings vector of the crop's record
                                        (lensim.restore.conditioning), only when the
                                        dataset is given a Conditioning with k > 0
    wiener (3, h, w) float32 in [0, 1]  the Wiener stage's image of the crop (cut and
                                        augmented with it), only when the dataset is
                                        given a stage cache folder
                                        (lensim.restore.psf_stage.ensure_wiener_cache)
with h = w = ``crop`` when sub-cropping, else the stored crop size.

Randomness (sub-crop position, dihedral op) is drawn from a generator seeded by
(seed, epoch, index), so an item's sample depends on nothing else: results are identical
whatever the worker count, batch order, or a resume in the middle of an epoch. Call
:meth:`PairDataset.set_epoch` at the start of each epoch.

Train/validation split: by source photo (:func:`split_sources`), never by crop, since the
crops of one photo overlap and share content.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import Dataset

from lensim.data.manifest import read_pairs_manifest
from lensim.errors import InputError
from lensim.images import read_image
from lensim.restore.conditioning import Conditioning, record_settings
from lensim.restore.fov import augment, fov_channels


@dataclass(frozen=True)
class CropRef:
    """One stored pair: file paths (absolute), sensor position of its top-left pixel, the
    source photo it was cut from and its record's shooting settings (record_settings: fno,
    focus_m, focal_mm; None when the pairs carry none)."""

    input: Path
    target: Path
    sensor_top: int
    sensor_left: int
    source: str
    settings: dict[str, float] | None = field(default=None, compare=False, hash=False)


def sensor_hw(manifest: dict[str, Any]) -> tuple[int, int]:
    """(height, width) of the manifest's sensor in pixels."""
    w, h = manifest["sensor"]["resolution"]
    return int(h), int(w)


def _source_key(record: dict[str, Any], i: int) -> str:
    src = record.get("source")
    return Path(str(src)).name if src else f"record-{record.get('index', i)}"


def crop_refs(dataset_dir: str | Path, manifest: dict[str, Any]) -> list[CropRef]:
    """Every crop of the manifest, in manifest order."""
    root = Path(dataset_dir)
    out = []
    for i, r in enumerate(manifest["records"]):
        key = _source_key(r, i)
        settings = None if r.get("settings") is None else record_settings(r["settings"], str(root), f"records[{i}]")
        for c in r["crops"]:
            out.append(
                CropRef(
                    root / c["input"], root / c["target"], int(c["sensor_top"]), int(c["sensor_left"]), key, settings
                )
            )
    return out


def split_sources(sources: Sequence[str], val_fraction: float, seed: int) -> tuple[list[str], list[str]]:
    """Deterministic split of source-photo names into (train, validation), sorted.

    Each name is ranked by sha256(seed:name); the first round(val_fraction * n) names (at
    least 1 when val_fraction > 0 and n >= 2, never all of them) go to validation. The
    result depends only on the set of names and the seed, not on their order.
    """
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    names = sorted(set(sources))
    n_val = 0
    if val_fraction > 0 and len(names) >= 2:
        n_val = min(len(names) - 1, max(1, round(val_fraction * len(names))))
    ranked = sorted(names, key=lambda s: hashlib.sha256(f"{seed}:{s}".encode()).hexdigest())
    val = sorted(ranked[:n_val])
    train = sorted(ranked[n_val:])
    return train, val


def item_generator(seed: int, epoch: int, index: int) -> torch.Generator:
    """The generator of one item's random draws in one epoch."""
    h = hashlib.sha256(f"{seed}:{epoch}:{index}".encode()).digest()
    return torch.Generator().manual_seed(int.from_bytes(h[:8], "little") >> 1)


class PairDataset(Dataset):
    """Aligned (aberrated, sharp, FOV) crops; see the module docstring.

    Args:
        refs: the crops to serve (from :func:`crop_refs`, usually filtered by a split).
        sensor_size: (height, width) of the sensor in pixels (FOV normalisation).
        crop: sub-crop size in pixels (random position), or None for the stored crops.
        augment: random dihedral op (0..7) with FOV-consistent channels.
        seed: seed of the per-item generators.
        cache: keep decoded images in memory (8-bit images as uint8: exact, 4x smaller).
        conditioning: the settings the network is conditioned on; when it has inputs
            (dim > 0) every item carries its record's settings vector (a record without
            settings is then a one-line InputError).
        wiener_dir: a Wiener stage cache folder (lensim.restore.psf_stage): every item
            carries its crop's stage image (16-bit PNG, read once when ``cache``).
    """

    def __init__(
        self,
        refs: Sequence[CropRef],
        sensor_size: tuple[int, int],
        crop: int | None = None,
        augment: bool = False,
        seed: int = 0,
        cache: bool = True,
        conditioning: Conditioning | None = None,
        wiener_dir: Path | None = None,
    ) -> None:
        if crop is not None and crop < 1:
            raise ValueError(f"crop must be positive, got {crop}")
        self.refs = list(refs)
        self.sensor_size = (int(sensor_size[0]), int(sensor_size[1]))
        self.crop = crop
        self.augment = augment
        self.seed = seed
        self.epoch = 0
        self.cache = cache
        self._cache: dict[int, tuple[torch.Tensor, ...]] = {}
        self.wiener_dir = None if wiener_dir is None else Path(wiener_dir)
        self.settings: list[torch.Tensor] | None = None
        if conditioning is not None and conditioning.dim:
            self.settings = [conditioning.vector(r.settings or {}, str(r.input)) for r in self.refs]

    @classmethod
    def from_folder(cls, dataset_dir: str | Path, sources: Sequence[str] | None = None, **kwargs: Any) -> PairDataset:
        """All crops of a pairs folder (or those of the named source photos)."""
        manifest = read_pairs_manifest(dataset_dir)
        refs = crop_refs(dataset_dir, manifest)
        if sources is not None:
            keep = set(sources)
            refs = [r for r in refs if r.source in keep]
        return cls(refs, sensor_hw(manifest), **kwargs)

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose random draws __getitem__ makes."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.refs)

    @staticmethod
    def _read(path: Path) -> tuple[torch.Tensor, int]:
        img, bits = read_image(path)
        if bits == 8:
            return torch.round(img * 255.0).to(torch.uint8), bits
        return img, bits

    def _load(self, i: int) -> tuple[torch.Tensor, ...]:
        """(input, target) of item i, and its Wiener stage image when the dataset has a cache."""
        if i in self._cache:
            return self._cache[i]
        ref = self.refs[i]
        inp, _ = self._read(ref.input)
        tgt, _ = self._read(ref.target)
        extra: tuple[torch.Tensor, ...] = ()
        if self.wiener_dir is not None:
            from lensim.restore.psf_stage import cached_path

            wien, _ = read_image(cached_path(self.wiener_dir, ref.input))
            if wien.shape != inp.shape:
                raise InputError(
                    str(cached_path(self.wiener_dir, ref.input)),
                    "size",
                    f"is {tuple(wien.shape)}; expected the shape of its input {ref.input.name} {tuple(inp.shape)}",
                )
            extra = (wien,)
        if inp.shape != tgt.shape:
            raise InputError(
                str(ref.target),
                "size",
                f"is {tuple(tgt.shape)}; expected the shape of its input {ref.input.name} {tuple(inp.shape)}",
            )
        if self.crop is not None and min(inp.shape[-2:]) < self.crop:
            raise InputError(
                str(ref.input),
                "size",
                f"is {inp.shape[-1]}x{inp.shape[-2]}; expected at least "
                f"{self.crop}x{self.crop} for {self.crop}-pixel training crops",
            )
        if self.cache:
            self._cache[i] = (inp, tgt, *extra)
        return (inp, tgt, *extra)

    @staticmethod
    def _float(x: torch.Tensor) -> torch.Tensor:
        return x.to(torch.float32) / 255.0 if x.dtype == torch.uint8 else x

    def __getitem__(self, i: int) -> dict[str, Any]:
        ref = self.refs[i]
        inp, tgt, *extra = self._load(i)
        _, h, w = inp.shape
        top, left = 0, 0
        gen = item_generator(self.seed, self.epoch, i)
        if self.crop is not None:
            top = int(torch.randint(0, h - self.crop + 1, (1,), generator=gen))
            left = int(torch.randint(0, w - self.crop + 1, (1,), generator=gen))
            h = w = self.crop
        op = int(torch.randint(0, 8, (1,), generator=gen)) if self.augment else 0
        planes = [self._float(x[:, top : top + h, left : left + w]) for x in (inp, tgt, *extra)]
        fov = fov_channels(h, w, ref.sensor_top + top, ref.sensor_left + left, *self.sensor_size)
        if op:
            both, fov = augment(torch.cat(planes), fov, op)
            planes = list(both.split(3))
        item = {"input": planes[0].contiguous(), "target": planes[1].contiguous(), "fov": fov, "index": i}
        if extra:
            item["wiener"] = planes[2].contiguous()
        if self.settings is not None:
            item["settings"] = self.settings[i]
        return item


__all__ = ["CropRef", "PairDataset", "crop_refs", "item_generator", "sensor_hw", "split_sources"]
