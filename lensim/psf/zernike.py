"""Zernike polynomials on the unit disc and least-squares fits of a wavefront to them.

Two conventions, named in every result:

* ``noll``: the standard Zernike polynomials in Noll's order and normalization (R. J. Noll,
  J. Opt. Soc. Am. 66, 207, 1976), as Zemax OpticStudio's "Zernike Standard
  Coefficients" use them: Z_j = sqrt(2 (n + 1)) R_n^|m|(rho) cos(m theta) (m > 0, even j)
  or sin(|m| theta) (m < 0, odd j), sqrt(n + 1) R_n^0 for m = 0. Each term has RMS 1 over
  the disc, so a coefficient is that term's RMS contribution. Terms 1..NOLL_MAX_TERMS.
* ``fringe``: the Fringe (University of Arizona) set of 37 terms, unnormalized (Z4 =
  2 rho^2 - 1, Z9 = 6 rho^4 - 6 rho^2 + 1, ...; Z37 the 12th-order spherical term), as
  Zemax's "Zernike Fringe Coefficients" use them.

Pupil coordinates: x = rho cos(theta), y = rho sin(theta), normalized to the unit disc;
theta is measured from +x towards +y. Plain NumPy (float64).
"""

from __future__ import annotations

import math

import numpy as np

from lensim.errors import InputError

CONVENTIONS = ("noll", "fringe")
NOLL_MAX_TERMS = 231  # radial orders up to 20
FRINGE_MAX_TERMS = 37
MAX_TERMS = {"noll": NOLL_MAX_TERMS, "fringe": FRINGE_MAX_TERMS}
CONVENTION_NAMES = {
    "noll": "Zernike standard (Noll order and normalization, RMS 1 per term; Zemax 'Zernike Standard')",
    "fringe": "Zernike Fringe (University of Arizona order, unnormalized, 37 terms; Zemax 'Zernike Fringe')",
}


def noll_nm(j: int) -> tuple[int, int]:
    """(n, m) of Noll term j >= 1; m > 0 for cos(m theta) terms, m < 0 for sin(|m| theta)."""
    if j < 1:
        raise InputError(None, "zernike_terms", f"expected a Noll index of at least 1, got {j}")
    n = 0
    while (n + 1) * (n + 2) // 2 < j:
        n += 1
    p = j - n * (n + 1) // 2  # 1 .. n + 1: position in the row
    orders = [0] if n % 2 == 0 else []
    orders += [a for a in range(2 - n % 2, n + 1, 2) for _ in (0, 1)]
    m = orders[p - 1]
    if m == 0:
        return n, 0
    return n, (m if j % 2 == 0 else -m)


def _fringe_table() -> list[tuple[int, int]]:
    """(n, m) of Fringe terms 1..37: rows by (n + |m|) / 2, within a row |m| falling, cos
    before sin; term 37 the 12th-order spherical term."""
    out: list[tuple[int, int]] = []
    for k in range(6):
        for a in range(k, -1, -1):  # a = |m|, n = 2 k - a
            n = 2 * k - a
            out += [(n, 0)] if a == 0 else [(n, a), (n, -a)]
    out.append((12, 0))
    return out


FRINGE_NM = _fringe_table()


def fringe_nm(j: int) -> tuple[int, int]:
    """(n, m) of Fringe term j (1..37)."""
    if not 1 <= j <= FRINGE_MAX_TERMS:
        raise InputError(None, "zernike_terms", f"expected a Fringe index in [1, {FRINGE_MAX_TERMS}], got {j}")
    return FRINGE_NM[j - 1]


def term_nm(convention: str, j: int) -> tuple[int, int]:
    """(n, m) of term j in a convention ('noll' or 'fringe')."""
    _check_convention(convention)
    return noll_nm(j) if convention == "noll" else fringe_nm(j)


def _check_convention(convention: str) -> None:
    if convention not in CONVENTIONS:
        raise InputError(None, "zernike_convention", f"expected one of {', '.join(CONVENTIONS)}, got {convention!r}")


def check_terms(convention: str, terms: int) -> int:
    """The number of terms, checked against what the convention supports."""
    _check_convention(convention)
    top = MAX_TERMS[convention]
    if not 1 <= terms <= top:
        raise InputError(None, "zernike_terms", f"expected 1 to {top} {convention} terms, got {terms}")
    return terms


def radial(n: int, m: int, rho: np.ndarray) -> np.ndarray:
    """The radial polynomial R_n^|m|(rho)."""
    a = abs(m)
    out = np.zeros_like(rho, dtype=np.float64)
    for k in range((n - a) // 2 + 1):
        c = (-1) ** k * math.factorial(n - k)
        c /= math.factorial(k) * math.factorial((n + a) // 2 - k) * math.factorial((n - a) // 2 - k)
        out = out + c * rho ** (n - 2 * k)
    return out


def zernike(convention: str, j: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Term j of a convention at pupil points (x, y) (arrays of one shape, unit disc)."""
    n, m = term_nm(convention, j)
    rho = np.hypot(x, y)
    theta = np.arctan2(y, x)
    ang = np.cos(m * theta) if m >= 0 else np.sin(-m * theta)
    value = radial(n, m, rho) * ang
    if convention == "noll":
        value = value * math.sqrt((n + 1) * (2 if m != 0 else 1))
    return value


def design_matrix(convention: str, terms: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(P, terms): terms 1..terms at the P points."""
    check_terms(convention, terms)
    return np.stack([zernike(convention, j, x, y) for j in range(1, terms + 1)], axis=-1)


def fit(convention: str, terms: int, x: np.ndarray, y: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Least-squares coefficients (terms,) of values (P,) at pupil points (x, y), equal
    weights; coefficient k is term k + 1. values' unit (waves) is the coefficients'."""
    x, y, values = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (x, y, values))
    a = design_matrix(convention, terms, x, y)
    if x.size < terms:
        raise InputError(None, "zernike_terms", f"expected at most {x.size} terms for {x.size} pupil samples")
    coeffs, *_ = np.linalg.lstsq(a, values, rcond=None)
    return coeffs


def term_name(n: int, m: int) -> str:
    """A short aberration name of a low-order (n, m) term ('' beyond the common ones)."""
    names = {
        (0, 0): "piston",
        (1, 1): "tilt x",
        (1, -1): "tilt y",
        (2, 0): "defocus",
        (2, 2): "astigmatism 0 deg",
        (2, -2): "astigmatism 45 deg",
        (3, 1): "coma x",
        (3, -1): "coma y",
        (3, 3): "trefoil x",
        (3, -3): "trefoil y",
        (4, 0): "primary spherical",
        (4, 2): "secondary astigmatism 0 deg",
        (4, -2): "secondary astigmatism 45 deg",
        (4, 4): "quadrafoil x",
        (4, -4): "quadrafoil y",
        (5, 1): "secondary coma x",
        (5, -1): "secondary coma y",
        (6, 0): "secondary spherical",
    }
    return names.get((n, m), "")
