"""A small sequential ray tracer of its own (spheres, planes, mirrors; no aspheres), written
for tests apart from lensim's tracer: the optical path of single rays to the exit-pupil
reference sphere, as a third computation beside lensim and its peers.

Geometry in mm, z along the axis from the first vertex; rays launched from the paraxial
entrance pupil (paraxial aiming: normalized pupil (px, py) times its radius) for an
object at infinity, a field angle in the y-z plane; refractive indices from the caller.
"""

from __future__ import annotations

import math

import numpy as np


def _intersect(p: np.ndarray, d: np.ndarray, z_vertex: float, curvature: float) -> np.ndarray:
    """Distance t (R,) along unit directions d (R, 3) from points p (R, 3) to the surface
    z - z_vertex = sag(curvature) (the branch through the vertex)."""
    q = p - np.array([0.0, 0.0, z_vertex])
    if curvature == 0.0:
        return -q[:, 2] / d[:, 2]
    b = d[:, 2] - curvature * (q * d).sum(-1)
    c = curvature * (q * q).sum(-1) - 2.0 * q[:, 2]
    return c / (b + np.sign(b) * np.sqrt(b * b - curvature * c))


def _normal(q: np.ndarray, curvature: float) -> np.ndarray:
    """Unit surface normals (R, 3) at local points q (R, 3)."""
    n = np.stack([curvature * q[:, 0], curvature * q[:, 1], curvature * q[:, 2] - 1.0], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _bend(d: np.ndarray, n: np.ndarray, mu: float | None) -> np.ndarray:
    """New unit directions: reflected (mu None) or refracted with index ratio mu = n1/n2."""
    n = n * np.sign((d * n).sum(-1))[:, None]  # along the ray
    cos_i = (d * n).sum(-1)
    if mu is None:
        return d - 2.0 * cos_i[:, None] * n
    cos_t = np.sqrt(1.0 - mu * mu * (1.0 - cos_i * cos_i))
    return mu * d + (cos_t - mu * cos_i)[:, None] * n


def trace_opl(
    surfaces: list[dict],
    indices: np.ndarray,
    z_image: float,
    z_entrance: float,
    ep_radius: float,
    angle_deg: float,
    pupil: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Trace rays at normalized pupil points (R, 2). surfaces: dicts with z (vertex),
    c (curvature, 1/mm), mirror (bool), obscuration (radius or 0); indices (N + 1,) of the
    media (absolute values). Returns image-plane points (R, 3), directions (R, 3),
    optical paths (R,) from the incoming plane wavefront through the pupil centre, and
    a validity mask (R,) (False: blocked by an obscuration)."""
    a = math.radians(angle_deg)
    d = np.tile([0.0, math.sin(a), math.cos(a)], (len(pupil), 1))
    p = np.stack([pupil[:, 0] * ep_radius, pupil[:, 1] * ep_radius, np.full(len(pupil), z_entrance)], -1)
    opl = indices[0] * ((p - np.array([0.0, 0.0, z_entrance])) * d).sum(-1)
    ok = np.ones(len(pupil), bool)
    for i, s in enumerate(surfaces):
        t = _intersect(p, d, s["z"], s["c"])
        p = p + t[:, None] * d
        opl = opl + indices[i] * t
        if s.get("obscuration"):
            ok &= np.hypot(p[:, 0], p[:, 1]) >= s["obscuration"]
        normal = _normal(p - np.array([0.0, 0.0, s["z"]]), s["c"])
        d = _bend(d, normal, None if s["mirror"] else indices[i] / indices[i + 1])
    t = (z_image - p[:, 2]) / d[:, 2]
    return p + t[:, None] * d, d, opl + indices[-1] * t, ok


def opd_waves(
    surfaces: list[dict],
    indices: np.ndarray,
    z_image: float,
    z_entrance: float,
    ep_radius: float,
    z_exit: float,
    angle_deg: float,
    pupil: np.ndarray,
    wavelength_um: float,
) -> tuple[np.ndarray, np.ndarray]:
    """OPD (R,) in waves, (chief ray's path - the ray's) / wavelength, on the reference sphere
    centred on the chief ray's image point through its crossing of the exit-pupil plane
    z_exit; and the validity mask (R,)."""
    rays = np.concatenate([np.zeros((1, 2)), pupil])
    img, d, opl, ok = trace_opl(surfaces, indices, z_image, z_entrance, ep_radius, angle_deg, rays)
    centre = img[0]
    cross = img[0] + (z_exit - img[0, 2]) / d[0, 2] * d[0]
    radius = float(np.linalg.norm(cross - centre))
    # each ray back from the image plane to the sphere: |img + s d - centre| = radius, s < 0
    q = img - centre
    b = (q * d).sum(-1)
    s = -b - np.sqrt(b * b - ((q * q).sum(-1) - radius * radius))
    on_sphere = opl + indices[-1] * s
    return (on_sphere[0] - on_sphere[1:]) / (wavelength_um * 1e-3), ok[1:]
