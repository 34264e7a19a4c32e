"""Decentre and tilt of a surface or of the image plane (as-built and toleranced lenses).

A surface's pose moves it rigidly away from the axis: its vertex to (dx, dy, z_vertex)
(decentre, mm) and its local axes rotated by R = Rx(tilt_x) Ry(tilt_y) (tilt about the
global x axis, then about the rotated y axis, degrees, right-handed, about the vertex),
as Zemax's coordinate break "decentre then tilt, and return" around one surface. Light
reaches the surface in the global frame, is carried into the surface's frame
(p' = R^T (p - v), d' = R^T d), intersected and refracted there as usual, and carried back
(p = R p' + v, d = R d'); the next surface's vertex stays where the prescription puts it.

A rigid element tilt about a pivot on the axis is the same tilt on every surface of the
element plus a decentre of each vertex by (R[0, 2], R[1, 2]) * (z_vertex - z_pivot)
(element_poses); the second-order axial shift (1 - cos) of the vertices is left out
(below 3e-6 mm for 1 mrad over 5 mm).
"""

from __future__ import annotations

import math

import torch

Pose = tuple[float, float, float, float]  # (decentre x mm, decentre y mm, tilt x deg, tilt y deg)
NO_POSE: Pose = (0.0, 0.0, 0.0, 0.0)


def rotation(tilt_x_deg: float, tilt_y_deg: float) -> torch.Tensor:
    """R = Rx(tilt_x) @ Ry(tilt_y) (3, 3) float64: columns are the surface's local axes
    in the global frame."""
    a, b = math.radians(tilt_x_deg), math.radians(tilt_y_deg)
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    rx = torch.tensor([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]], dtype=torch.float64)
    ry = torch.tensor([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]], dtype=torch.float64)
    return rx @ ry


def _vertex(dx: float, dy: float, z_vertex: float | torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """The vertex (dx, dy, z_vertex) mm as a (3,) tensor of like's dtype and device, stacked
    where a coordinate is a tensor, so that gradients reach decentres and thicknesses."""
    if any(isinstance(v, torch.Tensor) for v in (dx, dy, z_vertex)):
        return torch.stack([torch.as_tensor(v, dtype=like.dtype, device=like.device) for v in (dx, dy, z_vertex)])
    return torch.tensor([dx, dy, z_vertex], dtype=like.dtype, device=like.device)


def to_local(
    pose: Pose, z_vertex: float | torch.Tensor, pos: torch.Tensor, dirs: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Positions (..., 3) mm and directions (..., 3) from the global frame to the frame of
    a surface with this pose whose nominal vertex is at z_vertex (mm); positions relative
    to the vertex."""
    dx, dy, tx, ty = pose
    v = _vertex(dx, dy, z_vertex, pos)
    r = rotation(tx, ty).to(pos.device)
    return (pos - v) @ r, dirs @ r  # row vectors: p R == (R^T p)^T


def to_global(
    pose: Pose, z_vertex: float | torch.Tensor, pos: torch.Tensor, dirs: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The inverse of to_local: local positions (relative to the vertex) and directions
    (..., 3) back to the global frame."""
    dx, dy, tx, ty = pose
    v = _vertex(dx, dy, z_vertex, pos)
    rt = rotation(tx, ty).to(pos.device).T
    return pos @ rt + v, dirs @ rt


def element_poses(
    decentre_mm: tuple[float, float], tilt_deg: tuple[float, float], z_vertices: list[float], z_pivot: float
) -> list[Pose]:
    """The surface poses of a rigid element (or group) decentred by decentre_mm (x, y) and
    tilted by tilt_deg (x, y) about the axial point z_pivot (mm): one pose per surface
    vertex z (mm)."""
    r = rotation(*tilt_deg)
    out = []
    for z in z_vertices:
        lever = z - z_pivot
        out.append(
            (
                decentre_mm[0] + float(r[0, 2]) * lever,
                decentre_mm[1] + float(r[1, 2]) * lever,
                tilt_deg[0],
                tilt_deg[1],
            )
        )
    return out


def compose(a: Pose, b: Pose) -> Pose:
    """Two small poses added term by term (decentres and tilts add to first order)."""
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3])


def mirror_pose(pose: Pose) -> Pose:
    """The pose mirrored in the y-z plane (x -> -x): M Rx(a) Ry(b) M = Rx(a) Ry(-b) with
    M = diag(-1, 1, 1), so the x decentre and the tilt about y change sign (exact)."""
    dx, dy, tx, ty = pose
    return (-dx, dy, tx, -ty)


def rotate_pose(pose: Pose, angle_deg: float) -> Pose:
    """A pose seen from a frame rotated by angle_deg about the optical axis (counter-
    clockwise from +x to +y): the decentre vector and the tilt vector (tilts about x and y
    as a vector, exact to first order in the tilts) both rotate by -angle_deg."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    dx, dy, tx, ty = pose
    return (c * dx + s * dy, -s * dx + c * dy, c * tx + s * ty, -s * tx + c * ty)
