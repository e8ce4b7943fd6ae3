"""Surrogate triangles (paper Appendix A): the initial triangle and the fitted one.

:func:`enclosing_triangle` gives the initial triangle of a group of covered triangles;
:func:`fit_triangle` moves its three vertices to a local minimum of the functional
below (L-BFGS, analytic gradient, Numba kernels in :mod:`engine.kernels.trees.surrogate_fit`).
:func:`engine.trees.build.build_tree` keeps the fitted triangle only if its exact conservative
ε-region (:func:`region_volume`) is not larger than the initial one's.

The functional is evaluated in the group's normalised frame — covered vertices ``p_i``
centred on their mean and divided by their largest distance from it — so every
parameter is dimensionless. For surrogate vertices ``X = (x1, x2, x3)`` with unit
normal N (oriented like the covered faces' summed normal by the initial triangle):

    F(X) = w_ε · S_β(d(p_i, X))                      covered vertices → surrogate
         + w_paper · S_β(d(x_k, t_j))                surrogate vertices → covered triangles
         + α_area / 2 · |(x2 − x1) × (x3 − x1)|^(−2)
         + α_inside / β_normal · Σ_k mean_i max(0, (x_k − p_i)·N)^β_normal

``S_β(r) = (mean r^β)^(1/β)`` is a soft maximum (the paper's ``1/β Σ ‖·‖^β`` made
scale-free and overflow-safe). The paper's first term is the ``w_paper`` one: it pulls
the three vertices to the centre of the smallest enclosing ball, so alone it gives tiny
triangles with ε ≈ the group radius — ideal for a round group, poor for a flat one.
What prunes is ε, the distance *from* the covered geometry *to* the surrogate: that is
the ``w_ε`` term. That term alone has no force that shrinks the triangle (once every
vertex projects inside it, growing it changes no distance), so the default ``"epsilon"``
fit keeps the paper's term with weight 0.3 as the size term. The values below were
chosen on root ε-regions and on the contact search's triangle comparisons, measured by
``benchmarks/surrogates.py --sweep`` (full tables: docs/trees.md, "Surrogate fitting";
"comparisons" = summed over its random poses, 308 thousand unfitted, with the traversal
of 65b5e6c; bounding-sphere pre-pruning makes that 119 thousand unfitted, 109 fitted,
and the sweep flat within 0.4% except for ``weight_paper``):

* ``weight_paper`` = 0.3: 0 leaves the roots as they are (the ε-region of a sphere's
  root is 7.3× its bounding ball, 303 thousand comparisons); 0.03 / 0.1 / 0.2 / 0.3 /
  0.5 / 1 gave 248 / 237 / 230 / 226 / 252 / 286 thousand comparisons.
* ``beta`` = 64: "very high", as in the paper; 16 / 32 / 64 / 128 gave 230 / 227 / 226 /
  226 thousand comparisons and root ε-regions 1.63 / 1.42 / 1.36 / 1.32× the ball.
* ``alpha_area`` = 1e-4: a guard against degenerate triangles only; 0 / 1e-4 / 1e-3 /
  1e-2 gave 225.6 / 226.0 / 228.0 / 229.8 thousand comparisons.
* ``alpha_inside`` = 0: the one-sided normal penalty moves the triangle inwards, which
  never shrinks an ε-region: 1 gave 226.6 thousand comparisons, 100 gave 231.7 thousand
  and a root ε-region 5.0× the ball. It is on (1, ``beta_normal`` = 4) in ``"paper"``.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass
from types import MappingProxyType

import numpy as np

from engine.errors import InvalidArgumentError
from engine.kernels.trees import surrogate_fit as sf
from engine.kernels.trees import tree_build as tb

__all__ = [
    "DEFAULT_FIT",
    "FITS",
    "FitParameters",
    "enclosing_triangle",
    "fit_triangle",
    "functional",
    "largest_distance",
    "region_volume",
    "resolve_fit",
]


@dataclass(frozen=True)
class FitParameters:
    """Parameters of the functional (see the module docstring) and of the minimiser.

    beta, alpha_area, alpha_inside, beta_normal, weight_epsilon, weight_paper : float
        β, α_area, α_inside, β_normal, w_ε, w_paper (dimensionless)
    iterations : int — most L-BFGS steps
    history : int — L-BFGS memory (curvature pairs)
    tolerance : float — stop once a step lowers F by less than ``tolerance · (|F| + tolerance)``
    """

    beta: float
    alpha_area: float
    alpha_inside: float
    beta_normal: float
    weight_epsilon: float
    weight_paper: float
    iterations: int = 50
    history: int = 6
    tolerance: float = 1e-5

    def __post_init__(self) -> None:
        values = astuple(self)
        ok = all(isinstance(v, int | float) and np.isfinite(v) and v >= 0 for v in values)
        ok = ok and self.beta >= 2 and self.beta_normal >= 1 and self.history >= 1
        if not ok or self.weight_epsilon + self.weight_paper <= 0:
            raise InvalidArgumentError(
                "fit parameters must be finite and >= 0, with beta >= 2, beta_normal >= 1, "
                f"history >= 1 and a positive distance weight; got {self}"
            )

    @property
    def array(self) -> np.ndarray:
        """(6,) float64 — the kernel's ``params``."""
        return np.array(astuple(self)[: sf.N_PARAMS], dtype=np.float64)


FITS = MappingProxyType(
    {
        "initial": None,
        "epsilon": FitParameters(
            beta=64.0,
            alpha_area=1e-4,
            alpha_inside=0.0,
            beta_normal=4.0,
            weight_epsilon=1.0,
            weight_paper=0.3,
        ),
        "paper": FitParameters(
            beta=64.0,
            alpha_area=1e-4,
            alpha_inside=1.0,
            beta_normal=4.0,
            weight_epsilon=0.0,
            weight_paper=1.0,
        ),
    }
)
"""Named surrogate constructions for :func:`engine.trees.build.build_tree`: ``"initial"`` (no
fit), ``"epsilon"`` (the default) and ``"paper"`` (the paper's literal direction)."""
DEFAULT_FIT = "epsilon"


def resolve_fit(fit: str | FitParameters) -> FitParameters | None:
    """The parameters named by ``fit`` (a key of :data:`FITS`, or parameters themselves);
    None for no fit. Anything else raises :class:`~engine.errors.InvalidArgumentError`."""
    if isinstance(fit, FitParameters):
        return fit
    if not isinstance(fit, str) or fit not in FITS:
        raise InvalidArgumentError(
            f"fit must be one of {sorted(FITS)} or FitParameters, got {fit!r}"
        )
    return FITS[fit]


def region_volume(tri: np.ndarray, epsilon: float) -> float:
    """Volume of the ε-region of ``tri (3, 3)`` float64: 2·area·ε + perimeter·πε²/2 + 4/3·πε³."""
    return float(tb.region_volume(np.ascontiguousarray(tri, dtype=np.float64), float(epsilon)))


def largest_distance(points: np.ndarray, tri: np.ndarray) -> float:
    """Largest distance of ``points (m, 3)`` float64 from the triangle ``tri (3, 3)``: the
    exact conservative ε of a surrogate over its covered vertices (float)."""
    return float(
        tb.largest_distance(
            np.ascontiguousarray(points, dtype=np.float64),
            np.ascontiguousarray(tri, dtype=np.float64),
        )
    )


def enclosing_triangle(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Smallest enclosing equilateral triangle of ``points`` in their mid-height PCA plane.

    Parameters
    ----------
    points : (m, 3) float64 — covered vertices (m ≥ 1)
    tris : (t, 3, 3) float64 — covered triangles, for the orientation only

    Returns
    -------
    (3, 3) float64 — wound so that its normal agrees with the covered faces' summed normal
    (the kernel :func:`engine.kernels.trees.tree_build.enclosing_triangle` that tree builds use)
    """
    tris = np.asarray(tris, dtype=np.float64)
    summed = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]).sum(axis=0)
    out = np.empty((3, 3))
    tb.enclosing_triangle(np.ascontiguousarray(points, dtype=np.float64), summed, out)
    return out


def _frame(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (3,) and radius of ``points (m, 3)``: the normalised frame of a group."""
    centre = points.mean(axis=0)
    return centre, float(np.sqrt(((points - centre) ** 2).sum(axis=1).max()))


def functional(
    tri: np.ndarray, points: np.ndarray, tris: np.ndarray, params: FitParameters
) -> tuple[float, np.ndarray]:
    """The functional and its gradient, in the normalised frame of ``points``.

    Parameters
    ----------
    tri : (3, 3) float64 — surrogate vertices (world coordinates)
    points : (m, 3) float64 — covered vertices
    tris : (t, 3, 3) float64 — covered triangles
    params : FitParameters

    Returns
    -------
    value : float
    grad : (3, 3) float64 — ∂value/∂tri (world units: the frame's gradient / radius)
    """
    centre, radius = _frame(points)
    x = np.ascontiguousarray((tri - centre) / radius, dtype=np.float64)
    grad = np.empty((3, 3))
    value = sf.objective(
        x,
        np.ascontiguousarray((points - centre) / radius, dtype=np.float64),
        np.ascontiguousarray((tris - centre) / radius, dtype=np.float64),
        params.array,
        grad,
    )
    return float(value), grad / radius


def fit_triangle(
    points: np.ndarray, tris: np.ndarray, initial: np.ndarray, params: FitParameters
) -> np.ndarray:
    """Minimise the functional from ``initial``.

    Parameters
    ----------
    points : (m, 3) float64 — covered vertices
    tris : (t, 3, 3) float64 — covered triangles (used when ``weight_paper > 0``)
    initial : (3, 3) float64 — starting triangle
    params : FitParameters

    Returns
    -------
    (3, 3) float64 — the fitted triangle (``initial`` if the fit is not finite)
    """
    centre, radius = _frame(points)
    if not radius > 0:
        return initial.copy()
    x = np.ascontiguousarray((initial - centre) / radius, dtype=np.float64)
    local = np.ascontiguousarray((points - centre) / radius, dtype=np.float64)
    if params.weight_paper > 0:
        local_tris = np.ascontiguousarray((tris - centre) / radius, dtype=np.float64)
    else:
        local_tris = np.zeros((0, 3, 3))
    sf.minimise(
        x,
        local,
        local_tris,
        params.array,
        int(params.iterations),
        int(params.history),
        float(params.tolerance),
    )
    fitted = centre + radius * x
    return fitted if np.isfinite(fitted).all() else initial.copy()
