"""Object-space rays: where a ray of a field starts and where it points.

A ray is launched through a point (x, y) of the paraxial entrance-pupil plane z = z_ep.
Object at infinity: rays of one field are parallel, direction (0, sin a, cos a) for field
angle a (Zemax's sign convention), starting on the entrance-pupil plane; their OPL starts
at the plane wavefront through the origin. Finite object: rays start at the object point
(0, h, -distance) with OPL 0 (h = -(distance + z_ep) tan a for angle fields).
Lengths in mm, angles in degrees.
"""

from __future__ import annotations

import torch

from lensim.optics.lens import Lens
from lensim.optics.paraxial import ParaxialData
from lensim.optics.trace import DTYPE, Rays


def launch_at(
    lens: Lens, field: torch.Tensor, ep_xy: torch.Tensor, z_ep: float | torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(position, direction), each (..., 3), of the rays of launch field values `field`
    (deg or mm; broadcast against ep_xy[..., 0]) through the points ep_xy (..., 2) mm of
    the plane z = z_ep (a 0-dim tensor where gradients flow to the entrance pupil)."""
    fld, ex, ey = torch.broadcast_tensors(field, ep_xy[..., 0], ep_xy[..., 1])
    ez = z_ep.expand_as(ex) if isinstance(z_ep, torch.Tensor) else torch.full_like(ex, z_ep)
    through = torch.stack([ex, ey, ez], -1)
    if lens.infinite_object:  # one direction per field value: computed once, expanded over the points
        a = torch.deg2rad(field)
        return through, torch.stack([torch.zeros_like(a), torch.sin(a), torch.cos(a)], -1).expand(through.shape)
    d = lens.object_distance
    h = -(d + z_ep) * torch.tan(torch.deg2rad(fld)) if lens.launch_field_type == "angle" else fld
    src = torch.stack([torch.zeros_like(h), h, torch.full_like(h, -d)], -1)
    v = through - src
    return src, v / torch.linalg.norm(v, dim=-1, keepdim=True)


def launch(
    lens: Lens, field: torch.Tensor, pupil_xy: torch.Tensor, para: ParaxialData
) -> tuple[torch.Tensor, torch.Tensor]:
    """Object-space rays from field values (angle deg or object height mm, shape (F,))
    through entrance-pupil-plane points pupil_xy (P, 2) in mm. Returns (position,
    direction), each (F, P, 3)."""
    return launch_at(lens, field.reshape(-1, 1), pupil_xy.unsqueeze(0), para.entrance_pupil_z_mm)


def object_rays(lens: Lens, position: torch.Tensor, direction: torch.Tensor, n_object: torch.Tensor) -> Rays:
    """Rays with their starting OPL: plane wavefront through the origin for an object at
    infinity, zero at the object point otherwise."""
    if lens.infinite_object:  # the dot product term by term (a sum over a last axis of 3 is slow on CPU)
        p, d = position.unbind(-1), direction.unbind(-1)
        if position.requires_grad or direction.requires_grad or n_object.requires_grad:
            opl = n_object * (p[0] * d[0] + p[1] * d[1] + p[2] * d[2])
        else:  # the same sums with two temporaries (each fresh multi-MB tensor costs page faults)
            opl, term = p[0] * d[0], p[1] * d[1]
            opl.add_(term).add_(torch.mul(p[2], d[2], out=term))
            opl = n_object * opl
    else:
        opl = torch.zeros(position.shape[:-1], dtype=DTYPE, device=position.device) + 0 * n_object
    valid = torch.ones(opl.shape, dtype=torch.bool, device=position.device)
    return Rays(position, direction, opl, valid)
