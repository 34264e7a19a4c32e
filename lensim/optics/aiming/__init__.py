"""Ray aiming: from a field and a point of the pupil to a ray in object space.

A ray is named by its field (in the lens's field unit) and its normalized pupil
coordinates (px, py) in the unit disc; the chief ray is (0, 0). Where each part lives:

``modes``
    ``Aiming`` ("paraxial" or "real") and ``AIMINGS``, in plain Python: the command line
    checks and names them without loading torch or the tracer.
``sampling``
    Normalized pupil sampling patterns (points in the unit disc): ``square_grid``,
    ``square_grid_full``, ``hexapolar``, ``random_uniform``.
``launch``
    Where a ray starts and where it points: ``launch_at`` / ``launch`` (rays of launch
    field values through points of the paraxial entrance-pupil plane), ``object_rays``
    (their starting optical path).
``real``
    Real ray aiming, ``aim_real``: the entrance-plane points whose rays cross the real stop
    at (px, py) x the paraxial stop semi-diameter (Newton with backtracking, a meridian
    search for chief rays the paraxial guess misses, continuation from the chief ray).
``rays``
    The entry points: ``generate_rays`` (rays for every wavelength x field x pupil point,
    paraxial or real aiming), ``object_field`` (a field in the lens's unit to a launch
    value, image heights solved for), and the chief ray as a reference ray:
    ``chief_ray_image_height``, ``trace_chief_rays``, ``unobscured``,
    ``largest_chief_field``, ``describe_failure``.

Downstream, lensim.psf.pupil_field traces an aimed pupil grid of one object point to the
exit-pupil reference sphere: the secondary sources every PSF method starts from (the
PSF's input, so it lives with the PSF methods).

Each module uses only those above it. Only ``modes`` is imported here, so that
``import lensim.optics.aiming`` loads no torch: import the others by their module
(``from lensim.optics.aiming.rays import generate_rays``).
"""

from lensim.optics.aiming.modes import AIMINGS, Aiming

__all__ = ["AIMINGS", "Aiming"]
