"""Shape generators for the paper's experiments and for tests.

Every generator returns a :class:`engine.geometry.mesh.Mesh`. All shapes are closed and wound
counter-clockwise seen from outside (outward normals), except :func:`plane`, which is an
open square with normals +z. Bad arguments raise :class:`engine.errors.InvalidArgumentError`.
"""

from __future__ import annotations

import operator
from typing import Any

import numpy as np

from engine.errors import InvalidArgumentError
from engine.geometry.mesh import Mesh

__all__ = [
    "MAX_SUBDIVISIONS",
    "PAPER_UV_SPHERES",
    "box",
    "icosphere",
    "noisy_sphere",
    "paper_sphere",
    "plane",
    "stretched_sphere",
    "torus",
    "uv_sphere",
]

#: Largest icosphere subdivision level accepted (20 * 4**8 = 1,310,720 faces).
MAX_SUBDIVISIONS = 8

#: Paper triangle count -> (segments, rings) of :func:`uv_sphere`, with
#: ``2 * segments * (rings - 1)`` faces. 1,224 = 36 x 18 is the paper's; for the other
#: counts the factorisation closest to equal latitude and longitude steps (segments
#: ~ 2 rings, as 36 x 18 has) is chosen among those with the same count.
PAPER_UV_SPHERES: dict[int, tuple[int, int]] = {
    12: (6, 2),
    36: (6, 4),
    140: (14, 6),
    1224: (36, 18),
}


# ---------------------------------------------------------------------- validation
def _int(name: str, value: Any, lo: int, hi: int | None = None) -> int:
    if isinstance(value, (bool, np.bool_)):
        raise InvalidArgumentError(f"{name} must be an integer, got {value!r}")
    try:
        v = operator.index(value)
    except TypeError:
        raise InvalidArgumentError(f"{name} must be an integer, got {value!r}") from None
    if v < lo or (hi is not None and v > hi):
        rng = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise InvalidArgumentError(f"{name} must be {rng}, got {v}")
    return v


def _pos(name: str, value: Any, lo: float = 0.0, inclusive: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"{name} must be a real number, got {value!r}") from None
    if not np.isfinite(v) or v < lo or (v == lo and not inclusive):
        op = ">=" if inclusive else ">"
        raise InvalidArgumentError(f"{name} must be finite and {op} {lo}, got {value!r}")
    return v


def _vec(name: str, value: Any, n: int, positive: bool = False) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidArgumentError(f"{name} must be {n} real numbers, got {value!r}") from None
    if v.shape != (n,) or not np.isfinite(v).all() or (positive and not (v > 0).all()):
        what = "positive " if positive else ""
        raise InvalidArgumentError(f"{name} must be {n} finite {what}numbers, got {value!r}")
    return v


# ---------------------------------------------------------------------- spheres
def _unit_icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: (V, 3) float64 on the unit sphere and (20 * 4**k, 3) int64 faces."""
    p = (1.0 + np.sqrt(5.0)) / 2.0
    v = np.array(
        [[-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0], [0, -1, p], [0, 1, p],
         [0, -1, -p], [0, 1, -p], [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1]],
        dtype=np.float64,
    )  # fmt: skip
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )  # fmt: skip
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):
        # one midpoint per undirected edge, projected onto the sphere
        edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        uniq, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inverse.reshape(-1, 3) + len(v)  # midpoints of edges (01, 12, 20) per face
        a, b, c = f.T
        ab, bc, ca = m.T
        f = np.stack([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]], axis=0)
        f = f.transpose(2, 0, 1).reshape(-1, 3)
        v = np.vstack([v, mid])
    return v, f


def icosphere(subdivisions: int = 0, radius: float = 1.0) -> Mesh:
    """Icosahedron refined `subdivisions` times by midpoint subdivision.

    Each level splits every triangle into four and projects the new edge midpoints
    onto the sphere; all vertices lie at distance `radius` from the origin.

    Parameters
    ----------
    subdivisions : int, 0..MAX_SUBDIVISIONS
    radius : float, > 0

    Returns
    -------
    Mesh
        ``20 * 4**subdivisions`` faces, ``10 * 4**subdivisions + 2`` vertices.
    """
    k = _int("subdivisions", subdivisions, 0, MAX_SUBDIVISIONS)
    r = _pos("radius", radius)
    v, f = _unit_icosphere(k)
    return Mesh(r * v, f)


def uv_sphere(segments: int, rings: int, radius: float = 1.0) -> Mesh:
    """Latitude-longitude sphere about the z axis.

    Parameters
    ----------
    segments : int, >= 3
        Vertices around each latitude circle (longitude steps).
    rings : int, >= 2
        Bands from pole to pole (latitude steps); ``rings - 1`` latitude circles.
    radius : float, > 0

    Returns
    -------
    Mesh
        ``2 * segments * (rings - 1)`` faces: a fan of `segments` triangles at each pole
        and two triangles per quad in the ``rings - 2`` interior bands;
        ``segments * (rings - 1) + 2`` vertices, all at distance `radius`.
    """
    s = _int("segments", segments, 3)
    n = _int("rings", rings, 2)
    r = _pos("radius", radius)
    theta = np.pi * np.arange(1, n) / n  # polar angle of each latitude circle
    phi = 2.0 * np.pi * np.arange(s) / s
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack(
        [st * np.cos(phi), st * np.sin(phi), np.broadcast_to(ct, (n - 1, s))], axis=-1
    ).reshape(-1, 3)
    north, south = len(ring), len(ring) + 1
    v = np.vstack([ring, [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])
    j = np.arange(s)
    jn = (j + 1) % s
    faces = [np.stack([np.full(s, north), j, jn], axis=1)]
    for i in range(n - 2):  # band between circle i (upper) and i + 1
        a, b = i * s + j, i * s + jn
        c, d = (i + 1) * s + j, (i + 1) * s + jn
        faces += [np.stack([a, c, d], axis=1), np.stack([a, d, b], axis=1)]
    last = (n - 2) * s
    faces.append(np.stack([np.full(s, south), last + jn, last + j], axis=1))
    return Mesh(r * v, np.concatenate(faces))


def paper_sphere(n_triangles: int, radius: float = 1.0) -> Mesh:
    """The paper's UV sphere with `n_triangles` faces (12, 36, 140 or 1224).

    See :data:`PAPER_UV_SPHERES` for the (segments, rings) used.
    """
    if n_triangles not in PAPER_UV_SPHERES:
        raise InvalidArgumentError(
            f"no paper sphere with {n_triangles!r} triangles; available: {sorted(PAPER_UV_SPHERES)}"
        )
    return uv_sphere(*PAPER_UV_SPHERES[n_triangles], radius=radius)


def _sphere_noise(u: np.ndarray, rng: np.random.Generator, octaves: int) -> np.ndarray:
    """Smooth hierarchical noise at unit directions `u` (N, 3); (N,) float64 in [0, 1].

    Octave ``o`` sums random plane waves ``sin(w 2**o d.u + phase)`` (directions ``d``
    uniform on the sphere) with amplitude ``0.5**o``: coarse bumps plus finer detail.
    """
    waves, w0 = 8, 2.0
    total = np.zeros(len(u))
    for o in range(octaves):
        d = rng.normal(size=(waves, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        phase = rng.uniform(0.0, 2.0 * np.pi, size=waves)
        total += 0.5**o * np.sin(w0 * 2.0**o * (u @ d.T) + phase).sum(axis=1)
    span = np.ptp(total)
    return (total - total.min()) / span if span > 0 else np.zeros_like(total)


def noisy_sphere(
    subdivisions: int = 3,
    eta_r: float = 1.2,
    seed: int = 0,
    octaves: int = 4,
    radius: float = 1.0,
) -> Mesh:
    """Icosphere whose vertices are pushed outward by smooth seeded noise.

    Each vertex keeps its direction; its distance from the origin is
    ``radius * (1 + (eta_r - 1) * n)`` with ``n`` in [0, 1] the normalised noise, so all
    radii lie in ``[radius, radius * eta_r]`` and both ends are attained for
    ``eta_r > 1``. The surface is star-shaped about the origin, hence closed,
    outward-oriented and free of self-intersections.

    Parameters
    ----------
    subdivisions : int, 0..MAX_SUBDIVISIONS
    eta_r : float, >= 1
        Radius ratio; 1 gives the plain icosphere.
    seed : int, >= 0
        Same seed, same shape.
    octaves : int, 1..16
        Noise octaves (each halves the amplitude and doubles the frequency).
    radius : float, > 0
    """
    k = _int("subdivisions", subdivisions, 0, MAX_SUBDIVISIONS)
    eta = _pos("eta_r", eta_r, 1.0, inclusive=True)
    sd = _int("seed", seed, 0)
    oc = _int("octaves", octaves, 1, 16)
    r = _pos("radius", radius)
    u, f = _unit_icosphere(k)
    noise = _sphere_noise(u, np.random.default_rng(sd), oc)
    return Mesh(u * (r * (1.0 + (eta - 1.0) * noise))[:, None], f)


def stretched_sphere(
    subdivisions: int = 3, eta: float = 1.4, axis: int = 0, radius: float = 1.0
) -> Mesh:
    """Icosphere of `radius` scaled by `eta` (> 0) along coordinate `axis` (0, 1 or 2).

    The bounds are ``radius * eta`` along `axis` and `radius` along the others.
    """
    k = _int("subdivisions", subdivisions, 0, MAX_SUBDIVISIONS)
    e = _pos("eta", eta)
    ax = _int("axis", axis, 0, 2)
    r = _pos("radius", radius)
    v, f = _unit_icosphere(k)
    scale = np.full(3, r)
    scale[ax] *= e
    return Mesh(v * scale, f)


# ---------------------------------------------------------------------- other shapes
def plane(size: Any = (10.0, 10.0), divisions: int = 1, center: Any = (0.0, 0.0, 0.0)) -> Mesh:
    """Flat rectangle in the plane z = center[2], normals +z (an open mesh).

    Parameters
    ----------
    size : (2,) float, > 0
        Extent along x and y.
    divisions : int, >= 1
        Grid cells per side; ``2 * divisions**2`` faces, ``(divisions + 1)**2`` vertices.
    center : (3,) float
    """
    sz = _vec("size", size, 2, positive=True)
    n = _int("divisions", divisions, 1, 4096)
    c = _vec("center", center, 3)
    t = np.linspace(-0.5, 0.5, n + 1)
    x, y = np.meshgrid(t * sz[0], t * sz[1], indexing="xy")  # row i has y index i
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1) + c
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()  # (x_j, y_i)
    b, cc, d = a + 1, a + n + 1, a + n + 2  # +x, +y, +x+y
    f = np.concatenate([np.stack([a, b, d], axis=1), np.stack([a, d, cc], axis=1)])
    return Mesh(v, f)


def box(extents: Any = (1.0, 1.0, 1.0), center: Any = (0.0, 0.0, 0.0)) -> Mesh:
    """Axis-aligned box with edge lengths `extents` (3,) > 0 centred at `center` (3,).

    8 vertices, 12 outward-wound faces.
    """
    e = _vec("extents", extents, 3, positive=True)
    c = _vec("center", center, 3)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    v = (corners - 0.5) * e + c  # vertex index = 4x + 2y + z
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],  # x = 0, x = 1
         [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],  # y = 0, y = 1
         [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],  # z = 0, z = 1
    )  # fmt: skip
    return Mesh(v, f)


def torus(
    major_radius: float = 1.0,
    minor_radius: float = 0.3,
    major_segments: int = 32,
    minor_segments: int = 16,
) -> Mesh:
    """Ring torus about the z axis (non-convex, closed, outward).

    Parameters
    ----------
    major_radius : float, > minor_radius
        Distance from the z axis to the centre of the tube.
    minor_radius : float, > 0
        Tube radius.
    major_segments, minor_segments : int, >= 3
        Steps around the z axis and around the tube; ``2 * major * minor`` faces.
    """
    big = _pos("major_radius", major_radius)
    small = _pos("minor_radius", minor_radius)
    if not small < big:
        raise InvalidArgumentError(
            f"minor_radius ({small}) must be smaller than major_radius ({big})"
        )
    nu = _int("major_segments", major_segments, 3)
    nv = _int("minor_segments", minor_segments, 3)
    u = 2.0 * np.pi * np.arange(nu) / nu
    w = 2.0 * np.pi * np.arange(nv) / nv
    uu, ww = np.meshgrid(u, w, indexing="ij")  # vertex index = i * nv + j
    rho = big + small * np.cos(ww)
    v = np.stack([rho * np.cos(uu), rho * np.sin(uu), small * np.sin(ww)], axis=-1)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j  # next around z
    c = i * nv + (j + 1) % nv  # next around the tube
    d = ((i + 1) % nu) * nv + (j + 1) % nv
    f = np.concatenate(
        [np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)]
    )
    return Mesh(v.reshape(-1, 3), f)
