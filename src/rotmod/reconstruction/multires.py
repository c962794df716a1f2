"""Coarse-to-fine reconstruction: a coarse grid first, full resolution where the sky has flux.

A wide field's image is mostly empty, yet a full-resolution solve pays for every pixel in
every product.  :func:`coarse_to_fine` (``reconstruct(..., coarse=...)``):

1. **coarse**: the grid binned ``factor x factor`` and a response on it (a
   :class:`~rotmod.response.RadonResponse` at a loose tolerance when the response is one),
   a short maximum-likelihood solve (:class:`~rotmod.reconstruction.SGP`) there; the
   *support* is the coarse pixels whose flux is significant (``z_j^2 I_j > ts_cut``, with
   ``I_j`` the Fisher information of the pixel's flux, the score test's), the most
   significant first and at most ``max_pixels`` fine pixels of them, at full resolution
   (the coarse response's looser tolerance makes bright sources leave significant residue
   around them: uncapped, the wide field's support would be 150,400 pixels);
2. **fine**: the full-resolution problem restricted to the support
   (:class:`~rotmod.response.subset.PixelSubset`: the response's own columns, so the
   image is a solution of the full-resolution problem with the other pixels at 0), solved
   first by short SGP fits (*screening*, ``screen_iterations``) and, once the support stops
   growing (or the screening rounds are used up), by the method itself;
3. **check, at full resolution**: every pixel outside the support is tested for flux the
   data ask for, by the score test against the fitted model (``U_j = sum E P_ij (y/mu -
   1)``, ``I_j = sum E^2 P_ij^2 / mu``, ``TS_j = U_j^2 / I_j`` where ``U_j > 0``: one
   adjoint and one squared adjoint of the full response); pixels with ``TS_j > ts_cut``
   (and ``margin`` pixels around each) join the support and step 2 is repeated.  The
   method's solve is always checked: the result's ``max_ts_outside`` is its check's.

With ``ts_cut = 0`` the check is the Karush-Kuhn-Tucker condition of the full problem
(no pixel held at 0 has a positive likelihood gradient), so a converged
maximum-likelihood solve on the support is the full-resolution maximum (an active-set
method; tested where the solves converge).  The default
``ts_cut = 25`` (5 sigma) leaves at 0 the pixels whose flux the data support at less than
that, i.e. the noise peaks a full-resolution maximum-likelihood solve switches on;
docs/reconstruction.md measures what that changes against the full solve.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from rotmod._validate import as_int, as_scalar
from rotmod.errors import ParameterError
from rotmod.reconstruction.base import (
    ReconstructionResult,
    Reconstructor,
    StoppingRule,
    _safe_div,
)
from rotmod.reconstruction.data import ForwardModel, PoissonData, as_data
from rotmod.reconstruction.sgp import SGP
from rotmod.response.materialised import build_response
from rotmod.response.operator import ResponseOperator
from rotmod.response.radon import RadonResponse
from rotmod.response.subset import PixelSubset
from rotmod.sky import SkyGrid

__all__ = ["Refinement", "coarse_grid", "coarse_to_fine"]


@dataclass(frozen=True)
class Refinement:
    """How :func:`coarse_to_fine` refines (``reconstruct(..., coarse=Refinement(...))``;
    an int ``f`` there means ``Refinement(factor=f)``).

    Parameters
    ----------
    factor : int
        Fine pixels per coarse pixel along each axis (>= 2).
    tolerance : float
        Tolerance of the coarse :class:`~rotmod.response.RadonResponse` (it only locates
        flux; the fine solve uses the full response).
    iterations : int
        SGP iterations of the coarse solve (it only seeds the support).
    ts_cut : float
        Coarse pixels whose flux is significant at this TS start the support, and pixels
        outside it whose score TS exceeds it join it (>= 0; 0: every coarse pixel with
        flux, and the full problem's optimality condition).
    max_pixels : int
        Most fine pixels the coarse stage puts in the support (the check adds any others
        the data ask for).
    margin : int
        Fine pixels around each added pixel that join with it (>= 0; default 0: the check
        adds every pixel whose flux is significant, and with screening another round is
        cheap, while each pixel of margin costs every iteration of the method's solve).
    max_rounds : int
        Most fine solves with the method (>= 1), and most screening fits; the last check
        is reported either way.
    screen_iterations : int
        SGP iterations of the *screening* fits, which only grow the support: the support
        is solved by this short maximum-likelihood fit and checked until the check adds
        nothing (or ``max_rounds`` fits are done), and only then solved with the method
        (whose result is checked again).  0, or ``ts_cut = 0``: every round is the
        method's solve (the optimality check needs converged solves: against a short fit
        almost every pixel has a positive gradient).  >= 0.
    """

    factor: int = 5
    tolerance: float = 1e-2
    # 50 (was 100): with screening a coarse image that misses flux costs a short SGP fit
    # and a check, not a solve with the method; on the wide field 100 -> 50 took the coarse
    # stage from 51 s to 26 s and the image from 266 s to 212 s, the same sources on their
    # pixels (without screening it made the image slower, 326 s: docs/reconstruction.md).
    iterations: int = 50
    ts_cut: float = 25.0
    max_pixels: int = 1500
    margin: int = 0
    max_rounds: int = 4
    screen_iterations: int = 200

    def __post_init__(self) -> None:
        object.__setattr__(self, "factor", as_int(self.factor, "coarse.factor", 2))
        object.__setattr__(self, "tolerance", as_scalar(self.tolerance, "coarse.tolerance",
                                                        lo=0.0, lo_open=True, hi=0.1))
        object.__setattr__(self, "iterations", as_int(self.iterations, "coarse.iterations", 1))
        object.__setattr__(self, "ts_cut", as_scalar(self.ts_cut, "coarse.ts_cut", lo=0.0))
        object.__setattr__(self, "max_pixels", as_int(self.max_pixels, "coarse.max_pixels",
                                                      self.factor**2))
        object.__setattr__(self, "margin", as_int(self.margin, "coarse.margin", 0))
        object.__setattr__(self, "max_rounds", as_int(self.max_rounds, "coarse.max_rounds", 1))
        object.__setattr__(self, "screen_iterations",
                           as_int(self.screen_iterations, "coarse.screen_iterations", 0))


@dataclass
class _Round:
    kind: str  # "screen" (a short SGP fit that only grows the support) or "solve"
    pixels: int
    solve_s: float
    check_s: float
    max_ts_outside: float
    added: int


def coarse_grid(grid: SkyGrid, factor: int) -> SkyGrid:
    """``grid`` binned ``factor x factor``: coarse pixel ``(cy, cx)`` covers fine pixels
    ``[cy f, cy f + f) x [cx f, cx f + f)`` (a side that ``factor`` does not divide gets a
    last coarse pixel reaching past the field), same tangent point."""
    ny, nx = grid.shape
    cy, cx = -(-ny // factor), -(-nx // factor)
    pix = grid.pixel_size
    # The coarse pixel centres are the means of their fine pixels' centres (the TAN plane is
    # linear in the pixel index); the fine field's first centre is at center - (n - 1)/2 pix.
    sx = grid.center[0] + 0.5 * (cx * factor - nx) * pix
    sy = grid.center[1] + 0.5 * (cy * factor - ny) * pix
    return SkyGrid((cy, cx), factor * pix, center=(sx, sy), tangent=grid.tangent)


def _coarse_response(response: ResponseOperator, grid: SkyGrid,
                     tolerance: float) -> ResponseOperator:
    spec = response.spec
    if spec is None:
        raise ParameterError("response: coarse-to-fine needs a response with a spec "
                             "(instrument, grid, time bins, model, energy)")
    cspec = type(spec)(spec.instrument, grid, spec.time_bins, spec.model, spec.energy,
                       spec.distance, spec.dtype)
    if isinstance(response, RadonResponse):
        return RadonResponse(cspec, tolerance=tolerance)
    return build_response(cspec)


def _fine_pixels(mask_coarse: np.ndarray, factor: int, shape: tuple[int, int]) -> np.ndarray:
    """Fine-grid mask of the coarse pixels in ``mask_coarse``."""
    up = np.repeat(np.repeat(mask_coarse, factor, axis=0), factor, axis=1)
    return up[: shape[0], : shape[1]]


def _fisher_weights(model: ForwardModel, mu: np.ndarray) -> np.ndarray:
    """``E^2 / mu``: ``(P o P)^T`` of it is each pixel's Fisher information."""
    return model.E * model.E * _safe_div(np.ones_like(mu), mu)


def _score_ts(response: ResponseOperator, model: ForwardModel, mu: np.ndarray) -> np.ndarray:
    """Score TS of one more unit of flux in each pixel against the model ``mu`` (counts)."""
    u = response.adjoint(model.E * (_safe_div(model.data.counts, mu) - 1.0))
    info = response.adjoint_squared(_fisher_weights(model, mu))
    return _safe_div(np.square(np.maximum(u, 0.0)), np.asarray(info, dtype=float))


def _screen_start(previous: tuple[np.ndarray, np.ndarray] | None, pix: np.ndarray,
                  n_bg: int) -> np.ndarray | None:
    """The augmented start of a screening solve on the pixels ``pix`` (sorted): the previous
    screening fit ``(pixels, z)`` on the pixels it had, 0 on the new ones (SGP's scaling
    floor lets the gradient switch them on), its background amplitudes (``None`` when there
    is no previous fit: SGP's flat start)."""
    if previous is None:
        return None
    old_pix, z_old = previous
    z = np.zeros(pix.size + n_bg)
    z[np.searchsorted(pix, old_pix)] = z_old[: old_pix.size]
    z[pix.size:] = z_old[old_pix.size:]
    return z


def _refine(response: ResponseOperator, pdata: PoissonData, cls: type[Reconstructor],
            support: np.ndarray, ref: Refinement,
            **params: Any) -> tuple[ReconstructionResult, list[_Round]]:
    """Steps 2-3: solve on ``support`` (a boolean image, grown in place), check every other
    pixel at full resolution, grow the support by the pixels that fail, repeat.

    While the support grows, the solves are short SGP fits (``ref.screen_iterations``,
    each warm-started from the last): a check needs the bright flux in place, not the
    method's image, and the method's solve on a support that a check then grows is paid
    for nothing (on the wide field a first support missed a faint source: 31 % of the
    image's time).  Once a screening check adds nothing (or ``ref.max_rounds`` fits are
    done), the method solves the support and its result is checked; pixels that check adds
    bring another solve with the method.  Screening changes the route, and may add pixels
    an unconverged fit leaves residue at; the result is the method's solve on the final
    support.  With ``ts_cut = 0`` there is no screening (see :class:`Refinement`)."""
    model = ForwardModel(response, pdata)
    rounds: list[_Round] = []
    sub: PixelSubset | None = None
    grow = np.ones((2 * ref.margin + 1,) * 2, dtype=bool)
    screening = ref.screen_iterations > 0 and ref.ts_cut > 0
    screen_stop = (StoppingRule(max_iter=ref.screen_iterations, chi2_dof=None, rel_tol=None)
                   if screening else None)
    previous: tuple[np.ndarray, np.ndarray] | None = None
    while True:
        ts0 = time.perf_counter()
        pix = np.flatnonzero(support.ravel())
        # The method's solve after a screening round that added nothing has the same
        # pixels: keep their columns rather than copy them (0.5-0.8 GB on the wide field).
        if sub is None or not np.array_equal(sub.pixels, pix):
            sub = PixelSubset(response, pix, reuse=sub)
        if screening:
            solver: Reconstructor = SGP(sub, pdata, stopping=screen_stop)
            start = _screen_start(previous, pix, solver.model.size - pix.size)
            if start is not None:
                solver.warm_start(start)
            res = solver.run()
            previous = (pix, solver.z)
        else:
            res = cls(sub, pdata, **params).run()
        ts1 = time.perf_counter()
        ts = _score_ts(response, model, res.model_counts)
        ts[pix] = 0.0
        added = ndimage.binary_dilation((ts > ref.ts_cut).reshape(support.shape),
                                        grow) & ~support
        kind = "screen" if screening else "solve"
        rounds.append(_Round(kind, int(pix.size), ts1 - ts0, time.perf_counter() - ts1,
                             float(ts.max()), int(added.sum())))
        more = bool(added.any()) and sum(r.kind == kind for r in rounds) < ref.max_rounds
        if not screening and not more:
            return res, rounds
        # A screening round that adds nothing (or the last one allowed) hands the support to
        # the method; the method's check that adds pixels brings another solve.
        screening = screening and more
        support |= added


def coarse_to_fine(
    response: ResponseOperator,
    data: Any,
    cls: type[Reconstructor],
    refinement: Refinement | int = 5,
    **params: Any,
) -> ReconstructionResult:
    """Reconstruct on a coarse grid, then at full resolution on the pixels with flux.

    Parameters
    ----------
    response : ResponseOperator
        The full-resolution response; its grid must be a :class:`~rotmod.sky.SkyGrid`.
    data : PoissonData, FoldedProfiles or ndarray
    cls : Reconstructor subclass
        The method of the fine solves.
    refinement : Refinement or int
        The refinement's parameters (an int: the coarse factor).
    **params
        As for the method (``exposure``, ``background``, ``fit_background``, stopping and
        the method's own parameters); the stopping rule, callbacks and the method's
        parameters apply to the method's solves (the screening fits and the coarse solve
        have their own iteration counts).

    Returns
    -------
    ReconstructionResult
        The method's last solve's result with its images on the full grid (0 outside the
        support); ``extras`` add ``coarse_image``, ``support`` (boolean image: the pixels
        that solve was run on), ``max_ts_outside`` (the largest score TS its check left
        outside the support) and ``rounds`` (per fine round: ``kind``, ``"screen"`` or
        ``"solve"``, pixels, solve and check seconds, largest TS outside, pixels added).

    Raises
    ------
    ParameterError
        A grid other than a SkyGrid, or bad refinement parameters.
    """
    ref = refinement if isinstance(refinement, Refinement) else Refinement(factor=refinement)
    grid = response.grid
    if not isinstance(grid, SkyGrid):
        raise ParameterError("coarse: coarse-to-fine needs a response on a SkyGrid, got "
                             f"{type(grid).__name__}")
    t0 = time.perf_counter()
    pdata = as_data(data, exposure=params.pop("exposure", None),
                    background=params.pop("background", None),
                    fit_background=params.pop("fit_background", None))
    params.pop("grid", None)
    shape = grid.shape
    # 1. coarse: where the flux is.
    cgrid = coarse_grid(grid, ref.factor)
    cresp = _coarse_response(response, cgrid, ref.tolerance)
    csolve = SGP(cresp, pdata, stopping=StoppingRule(max_iter=ref.iterations, chi2_dof=None,
                                                     rel_tol=None))
    cres = csolve.run()
    cimg = cres.image
    cmodel = ForwardModel(cresp, pdata)
    cinfo = np.asarray(cresp.adjoint_squared(_fisher_weights(cmodel, cres.model_counts)))
    # The most significant first, at most max_pixels fine pixels of them.
    cts = np.where(cimg > 0, np.square(cimg) * cinfo.reshape(cimg.shape), 0.0).ravel()
    keep = np.argsort(-cts, kind="stable")[: ref.max_pixels // ref.factor**2]
    cmask = np.zeros(cimg.size, dtype=bool)
    cmask[keep[cts[keep] > ref.ts_cut]] = True
    if not cmask.any():
        # Nothing significant at the coarse scale (an empty or faint sky): start from the
        # most significant coarse pixel; the full-resolution check adds what the sky needs.
        cmask[keep[0]] = True
    cmask = cmask.reshape(cimg.shape)
    support = _fine_pixels(cmask, ref.factor, shape)
    t_coarse = time.perf_counter() - t0
    # 2-3. fine solves on the support, checked at full resolution.
    res, rounds = _refine(response, pdata, cls, support, ref, **params)
    pix = np.flatnonzero(support.ravel())
    # The result on the full grid.
    full = np.zeros(grid.size)
    full[pix] = res.image.ravel()
    res.image = full.reshape(shape)
    for key, val in list(res.extras.items()):
        arr = np.asarray(val) if isinstance(val, np.ndarray) else None
        if arr is not None and arr.shape[-2:] == (1, pix.size):
            out = np.zeros((*arr.shape[:-2], grid.size))
            out[..., pix] = arr.reshape(*arr.shape[:-2], pix.size)
            res.extras[key] = out.reshape(*arr.shape[:-2], *shape)
    res.grid = grid
    res.run_time = time.perf_counter() - t0
    res.params.update(coarse=ref.factor, coarse_tolerance=ref.tolerance,
                      coarse_iterations=ref.iterations, ts_cut=ref.ts_cut,
                      max_pixels=ref.max_pixels, margin=ref.margin,
                      max_rounds=ref.max_rounds,
                      screen_iterations=ref.screen_iterations)
    res.extras.update(
        coarse_image=cimg, support=support.copy(), max_ts_outside=rounds[-1].max_ts_outside,
        coarse_s=t_coarse,
        rounds=[{"kind": r.kind, "pixels": r.pixels, "solve_s": r.solve_s,
                 "check_s": r.check_s, "max_ts_outside": r.max_ts_outside,
                 "added": r.added} for r in rounds],
    )
    return res
