"""The response as a linear operator from sky to folded count rates: the abstract
:class:`ResponseOperator`, :class:`BlockwiseResponse` (products over blocks of ``P``) and
:class:`MaterialisedResponse` (``P`` in memory, what :meth:`ResponseOperator.materialise`
returns).

``O[d, t] = sum_n P[d, t, n] S[n]``: ``S[n]`` is the photon rate that sky pixel ``n`` would
give on one (unobstructed) detector face, ``O[d, t]`` the expected count rate of detector
``d`` in time (mask-angle) bin ``t``.  Reconstruction algorithms see only :meth:`forward`,
:meth:`adjoint` and :meth:`sensitivity`; whether ``P`` is stored is an implementation detail.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import cached_property
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

import rotmod
from rotmod.errors import ParameterError
from rotmod.limits import check_memory
from rotmod.profiles.base import ProfileModel
from rotmod.response._plan import fold_half_turn, repeat_half_turn
from rotmod.response.parallel import Block, block_grid, block_ranges, iter_blocks
from rotmod.response.spec import ResponseSpec, check_field, describe

if TYPE_CHECKING:
    from scipy.sparse.linalg import LinearOperator  # ~0.15 s, for scipy's solvers only

__all__ = ["BlockwiseResponse", "MaterialisedResponse", "ResponseOperator"]


def _finite(x: np.ndarray, name: str) -> np.ndarray:
    """``x`` if every value is a finite number: a NaN or inf in a product's input would
    spread to every output value (one NaN pixel makes every rate NaN) with no error."""
    try:
        ok = np.isfinite(x)
    except TypeError:
        raise ParameterError(f"{name} must hold numbers, got values of type {x.dtype}") from None
    if not ok.all():
        i = np.unravel_index(int(np.argmin(ok)), x.shape)
        where = int(i[0]) if len(i) == 1 else tuple(int(k) for k in i)
        raise ParameterError(f"{name} must be finite, got {x[i]} at index {where} "
                             f"({int(x.size - ok.sum())} of {x.size} values not finite)")
    return x


class ResponseOperator(ABC):
    """Abstract response ``P``: sky vectors ``(n_sky,)`` to folded rates ``(n_det, n_time)``.

    Subclasses set :attr:`n_det`, :attr:`n_time`, :attr:`n_sky` (or adopt a
    :class:`~rotmod.response.ResponseSpec`, :meth:`_adopt`) and implement :meth:`_forward`
    and :meth:`_adjoint`; :meth:`block` and :meth:`materialise` have defaults built on
    :meth:`forward` that subclasses replace with something faster.

    Notes
    -----
    ``forward(S)[d, t] = sum_n P[d, t, n] S[n]`` and
    ``adjoint(Y)[n] = sum_{d, t} P[d, t, n] Y[d, t]``; every implementation passes the dot
    test ``<P x, y> = <x, P^T y>``.
    """

    n_det: int
    n_time: int
    n_sky: int
    #: Floating type of the products (float32 or float64).
    dtype: np.dtype = np.dtype(np.float64)
    #: Optional metadata: the instrument, sky grid, time binning, profile model and energy
    #: the response was computed for (``None`` when unknown, e.g. a matrix from elsewhere).
    instrument: Any = None
    grid: Any = None
    time_bins: Any = None
    model: ProfileModel | None = None
    energy: float | None = None
    #: Distance of the sources (cm) for a lab field; ``None``: at infinity.
    distance: float | None = None
    #: What the response was computed from (``None`` for a matrix from elsewhere); the
    #: attributes above are its fields, and :meth:`metadata` describes it.
    spec: ResponseSpec | None = None
    #: How :func:`~rotmod.response.save_response` stores this operator: a name in
    #: :data:`rotmod.response.stored.STORE_KINDS` ("dense": the values ``P``, in chunks).
    store_kind: ClassVar[str] = "dense"
    #: What a response held as one matrix is the sum of (``(weights, spec)`` pairs, e.g. a
    #: drift response's attitude intervals), kept so that it can be re-evaluated at other
    #: positions (:meth:`components`); ``None``: the response of :attr:`spec` itself.
    sum_of: list[tuple[np.ndarray | None, ResponseSpec]] | None = None

    def _adopt(self, spec: ResponseSpec) -> None:
        """Take the shape, dtype and metadata attributes from ``spec``."""
        self.spec = spec
        self.n_det, self.n_time, self.n_sky = spec.shape
        self.dtype = spec.dtype
        self.instrument, self.grid, self.time_bins = spec.instrument, spec.grid, spec.time_bins
        self.model, self.energy, self.distance = spec.model, spec.energy, spec.distance

    def components(self) -> list[tuple[np.ndarray | None, ResponseSpec]]:
        """What the response is a sum of: ``(weights, spec)`` pairs, ``P = sum_k W_k P_k``.

        ``weights`` (``(n_time,)``, or ``None`` for 1) multiply the response of ``spec``
        bin by bin.  One pair for a response computed for one spec; a drifting
        observation (:class:`~rotmod.response.DriftResponse`) has one per attitude
        interval.  This is how the response is re-evaluated at other sky positions
        (:func:`rotmod.response.columns_at`): a source between pixels.

        Raises
        ------
        ParameterError
            The response has no spec (a matrix from elsewhere).
        """
        if self.spec is None:
            raise ParameterError(
                "response has no spec (instrument, grid, model, energy), so it cannot be "
                "evaluated at other sky positions; build it with rotmod.response")
        if self.sum_of is not None:
            return list(self.sum_of)
        return [(None, self.spec)]

    @property
    def n_distinct(self) -> int:
        """Leading time bins that determine all (``ResponsePlan.n_distinct``); the others
        repeat them.  Default: every bin is distinct."""
        return self.n_time

    def __repr__(self) -> str:
        extra = "" if self.model is None else f", model {self.model.name!r}"
        if self.energy is not None:
            extra += f", {self.energy:g} keV"
        if self.distance is not None:
            extra += f", sources at {self.distance:g} cm"
        return (
            f"<{type(self).__name__} {self.n_det} detectors x {self.n_time} time bins x "
            f"{self.n_sky} sky pixels, {np.dtype(self.dtype).name}{extra}>"
        )

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_det * n_time, n_sky)``, the shape of the flattened matrix."""
        return (self.n_det * self.n_time, self.n_sky)

    def _check_sky(self, sky: Any) -> np.ndarray:
        x = np.asarray(sky)
        if x.shape != (self.n_sky,):
            raise ParameterError(f"sky must have shape ({self.n_sky},), got {x.shape}")
        return _finite(x, "sky")

    def _check_counts(self, counts: Any) -> np.ndarray:
        y = np.asarray(counts)
        if y.shape != (self.n_det, self.n_time):
            raise ParameterError(
                f"counts must have shape ({self.n_det}, {self.n_time}), got {y.shape}"
            )
        return _finite(y, "counts")

    def forward(self, sky: np.ndarray) -> np.ndarray:
        """``P S``: folded rates ``(n_det, n_time)`` of sky vector ``sky`` ``(n_sky,)``."""
        return self._forward(self._check_sky(sky))

    def adjoint(self, counts: np.ndarray) -> np.ndarray:
        """``P^T Y``: sky vector ``(n_sky,)`` of folded data ``counts`` ``(n_det, n_time)``."""
        return self._adjoint(self._check_counts(counts))

    def forward_detectors(self, sky: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``(P S)[detectors]``: folded rates ``(len(detectors), n_time)`` of some detectors.

        For block-iterative solvers (ordered subsets).  The default computes the whole
        product and keeps the rows; operators that can do less work override it.
        """
        return self.forward(sky)[np.asarray(detectors)]

    def adjoint_detectors(self, counts: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``P_D^T Y``: sky vector ``(n_sky,)`` of data ``(len(detectors), n_time)`` of some
        detectors ``D`` (the others taken as 0).  Default: the full adjoint, zero-padded."""
        det = np.asarray(detectors)
        full = np.zeros((self.n_det, self.n_time), dtype=np.result_type(counts, np.float32))
        full[det] = counts
        return self.adjoint(full)

    def adjoint_squared(self, counts: np.ndarray) -> np.ndarray:
        """``(P o P)^T Y``: ``sum_{d, t} P[d, t, n]^2 Y[d, t]``, the adjoint of ``P``'s
        element-wise square.

        With ``Y`` a weight per bin (``1/mu``) this is the Fisher information of a point
        source's flux in every pixel at once: what a TS map's score screen needs
        (:func:`rotmod.sources.ts_map` with ``exact_above``).  The default walks the blocks
        of ``P`` (one pass over its values, distributed as :meth:`materialise` is);
        operators that can do it without the values replace it.

        Parameters
        ----------
        counts : ndarray, shape (n_det, n_time)

        Returns
        -------
        ndarray, shape (n_sky,)
            float64.
        """
        y = fold_half_turn(np.asarray(self._check_counts(counts), dtype=np.float64),
                           self.n_distinct)
        out = np.zeros(self.n_sky)
        for _, (_, (n0, n1)), part in iter_blocks(
                self._source, self._materialise_blocks(), y, reduce=_squared_block,
                **self._run_options()):
            out[n0:n1] += part
        return out

    def _check_pixels(self, pixels: Any) -> np.ndarray:
        """Pixel indices checked, and the memory of their columns."""
        idx = np.atleast_1d(np.asarray(pixels))
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer) or (
                idx.size and (idx.min() < 0 or idx.max() >= self.n_sky)):
            raise ParameterError(f"pixels must be integer indices in [0, {self.n_sky - 1}], "
                                 f"got {pixels!r}")
        check_memory(float(self.n_det) * self.n_time * idx.size * self.dtype.itemsize,
                     f"a response of {self.n_det} x {self.n_time} x {idx.size} values",
                     hint="ask for fewer pixels at a time")
        return idx

    def columns(self, pixels: Any) -> np.ndarray:
        """``P[:, :, pixels]``: the values this operator uses for some sky pixels.

        The default evaluates a :meth:`block` per pixel; operators that hold ``P`` or
        evaluate it pixel by pixel replace it.

        Parameters
        ----------
        pixels : sequence of int
            Sky pixel indices (flattened grid order).

        Returns
        -------
        ndarray, shape (n_det, n_time, len(pixels))
            In this operator's dtype.

        Raises
        ------
        ParameterError
            Indices that are not integers in ``[0, n_sky)``.
        MemoryBudgetError
            If the result does not fit the memory budget.
        """
        idx = self._check_pixels(pixels)
        out = np.empty((self.n_det, self.n_time, idx.size), dtype=self.dtype)
        for k, pixel in enumerate(idx):
            out[:, :, k] = self.block(n=(int(pixel), int(pixel) + 1))[:, :, 0]
        return out

    @cached_property
    def _sensitivity(self) -> np.ndarray:
        return self._adjoint(np.ones((self.n_det, self.n_time)))

    def sensitivity(self) -> np.ndarray:
        """``P^T 1``: summed response of every sky pixel ``(n_sky,)``."""
        return self._sensitivity

    @abstractmethod
    def _forward(self, sky: np.ndarray) -> np.ndarray: ...

    @abstractmethod
    def _adjoint(self, counts: np.ndarray) -> np.ndarray: ...

    def as_linear_operator(self) -> LinearOperator:
        """A `scipy.sparse.linalg.LinearOperator` on flattened vectors.

        The operator is declared float64 and returns float64 vectors (products of a float32
        response are computed in float32 and then widened), which is what scipy's iterative
        solvers (``lsqr``, ``cg``, ...) expect.
        """
        from scipy.sparse.linalg import LinearOperator  # ~0.15 s, for scipy's solvers only

        return LinearOperator(
            self.shape,
            matvec=lambda x: self.forward(np.ravel(x)).ravel().astype(np.float64, copy=False),
            rmatvec=lambda y: self.adjoint(np.reshape(y, (self.n_det, self.n_time))).astype(
                np.float64, copy=False
            ),
            dtype=np.float64,
        )

    def block(
        self, t: tuple[int, int] | None = None, n: tuple[int, int] | None = None
    ) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]`` (``None`` = the whole axis), in :attr:`dtype`.

        Every implementation checks the ranges the same way
        (:func:`~rotmod.response.parallel.block_ranges`: integers, ``0 <= t0 < t1 <=
        n_time``, ``0 <= n0 < n1 <= n_sky``; else :class:`~rotmod.errors.ParameterError`).
        The default computes the columns as products with unit sky vectors (one
        :meth:`forward` per pixel); operators that hold or evaluate ``P`` replace it.
        """
        (t0, t1), (n0, n1) = block_ranges(t, n, self.n_time, self.n_sky)
        out = np.empty((self.n_det, t1 - t0, n1 - n0), dtype=self.dtype)
        unit = np.zeros(self.n_sky)
        for k, pixel in enumerate(range(n0, n1)):
            unit[pixel] = 1.0
            out[:, :, k] = self.forward(unit)[:, t0:t1]
            unit[pixel] = 0.0
        return out

    def materialise(self) -> MaterialisedResponse:
        """The whole matrix ``P`` held in memory: the one way to get the values of any
        response (computed, read from a store or already held).

        Returns
        -------
        MaterialisedResponse
            With this operator's :attr:`spec` (or, without one, its metadata attributes).
        """
        out = np.empty((self.n_det, self.n_time, self.n_sky), dtype=self.dtype)
        for _, ((t0, t1), (n0, n1)), p in iter_blocks(
            self._source, self._materialise_blocks(), **self._run_options()
        ):
            out[:, t0:t1, n0:n1] = p
        repeat_half_turn(out, self.n_distinct)
        if self.spec is not None:
            return MaterialisedResponse(out, spec=self.spec, sum_of=self.sum_of)
        return MaterialisedResponse(
            out, instrument=self.instrument, grid=self.grid, time_bins=self.time_bins,
            model=self.model, energy=self.energy, distance=self.distance,
        )

    # -- hooks of the block walk (iter_blocks) ---------------------------------------------

    @property
    def _source(self) -> Any:
        """What evaluates the blocks: this operator, or something picklable for a cluster."""
        return self

    def _run_options(self) -> dict[str, Any]:
        """``scheduler``, ``client``, ``progress`` of the block walk (default local)."""
        return {}

    def _materialise_blocks(self) -> list[Block]:
        """Blocks over the distinct bins that :meth:`materialise` walks (~32 MB each)."""
        return block_grid((self.n_det, self.n_distinct, self.n_sky))

    def metadata(self) -> dict[str, Any]:
        """Everything needed to reproduce this response, as plain (JSON-able) values.

        Keys: ``instrument`` (:meth:`Instrument.to_dict`), ``grid`` (:meth:`SkyGrid.to_dict`),
        ``time_bins`` (:meth:`TimeBinning.to_dict`), ``model`` (``ProfileModel.describe()``),
        ``energy`` (keV or ``None``), ``dtype``, ``shape`` ``[n_det, n_time, n_sky]`` and
        ``rotmod_version``; unknown entries are ``None``.  A response for sources at a finite
        distance adds ``distance`` (cm).  With a :attr:`spec`, the fields are
        :meth:`ResponseSpec.to_dict`.
        """
        if self.spec is not None:
            fields = self.spec.to_dict()
        else:
            fields = describe(self.instrument, self.grid, self.time_bins, self.model,
                              self.energy, self.dtype, (self.n_det, self.n_time, self.n_sky),
                              self.distance)
        distance = fields.pop("distance", None)
        return {
            **fields,
            "rotmod_version": rotmod.__version__,
            # Only when finite, so that responses at infinity describe themselves as before.
            **({} if distance is None else {"distance": distance}),
            # Only for a sum (a drift): each part's weights and grid (its attitude).
            **({} if self.sum_of is None else {"sum_of": [
                {"weights": None if w is None else np.asarray(w, float).tolist(),
                 "grid": spec.grid.to_dict()} for w, spec in self.sum_of]}),
        }


class MaterialisedResponse(ResponseOperator):
    """A response held in memory as ``P[d, t, n]``.

    Parameters
    ----------
    matrix : ndarray, shape (n_det, n_time, n_sky)
        The response, float32 or float64 (other types are refused; the array is used as
        is, without a copy, when it is C-contiguous).
    spec : ResponseSpec, optional
        What the matrix was computed for (its shape and dtype must be the spec's).
    instrument, grid, time_bins, model, energy, distance : optional
        Without a spec, what is known of it.  With ``instrument``, ``grid``, ``time_bins``
        and ``model`` (``energy`` and ``distance`` optional) they make the :attr:`spec`
        (of the matrix's dtype); otherwise they are loose metadata (see
        :meth:`ResponseOperator.metadata`) and :attr:`spec` is ``None``.  Each is checked
        by the spec's own validator (:func:`~rotmod.response.spec.check_field`) and
        against the matrix's sizes.  ``model`` may be a registry name or instance;
        ``distance`` (cm) of a lab field's sources.
    sum_of : list of (weights, ResponseSpec), optional
        With ``spec``: what the matrix is the sum of (a drift response's intervals; see
        :attr:`ResponseOperator.sum_of`).

    Raises
    ------
    ParameterError
        If ``matrix`` is not a 3-D float32/float64 array, or does not fit the metadata.

    Notes
    -----
    With ``A = P.reshape(n_det * n_time, n_sky)``, ``forward(S) = (A S).reshape(n_det,
    n_time)`` and ``adjoint(Y) = Y.ravel() A``: one BLAS matrix-vector product each, in the
    matrix's dtype (inputs are cast to it).
    """

    def __init__(
        self,
        matrix: np.ndarray,
        *,
        spec: ResponseSpec | None = None,
        instrument: Any = None,
        grid: Any = None,
        time_bins: Any = None,
        model: str | ProfileModel | None = None,
        energy: float | None = None,
        distance: float | None = None,
        sum_of: list[tuple[np.ndarray | None, ResponseSpec]] | None = None,
    ) -> None:
        m = np.asarray(matrix)
        if m.ndim != 3:
            raise ParameterError(f"matrix must have shape (n_det, n_time, n_sky), got {m.shape}")
        if m.dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
            raise ParameterError(f"matrix must be float32 or float64, got {m.dtype}")
        self.matrix = np.ascontiguousarray(m)
        if spec is not None:
            loose = (instrument, grid, time_bins, model, energy, distance)
            if any(v is not None for v in loose):
                raise ParameterError("pass either spec or instrument, grid, time_bins, model, "
                                     "energy, distance, not both")
            if spec.shape != m.shape or spec.dtype != m.dtype:
                raise ParameterError(f"matrix must have the spec's shape {spec.shape} and dtype "
                                     f"{spec.dtype}, got {m.shape} {m.dtype}")
            self._adopt(spec)
            self.sum_of = sum_of
            return
        # Each field is checked by the spec's own validator (check_field), then against the
        # matrix's sizes; with every field a spec needs, the matrix adopts a spec.
        given = {"instrument": instrument, "grid": grid, "time_bins": time_bins,
                 "model": model, "energy": energy, "distance": distance}
        fields = {k: check_field(k, v) for k, v in given.items() if v is not None}
        _check_sizes(m.shape, fields)
        if all(k in fields for k in ("instrument", "grid", "time_bins", "model")):
            self._adopt(ResponseSpec(**fields, dtype=m.dtype))
            return
        self.n_det, self.n_time, self.n_sky = (int(v) for v in m.shape)
        self.dtype = m.dtype
        for k, v in fields.items():
            setattr(self, k, v)

    @property
    def _flat(self) -> np.ndarray:
        return self.matrix.reshape(self.n_det * self.n_time, self.n_sky)

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        x = np.asarray(sky, dtype=self.dtype)
        return (self._flat @ x).reshape(self.n_det, self.n_time)

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        y = np.asarray(counts, dtype=self.dtype).ravel()
        return y @ self._flat

    def forward_detectors(self, sky: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``(P S)[detectors]``: only those detectors' rows (one product per detector)."""
        x = np.asarray(self._check_sky(sky), dtype=self.dtype)
        return np.stack([self.matrix[d] @ x for d in np.asarray(detectors).ravel()])

    def adjoint_detectors(self, counts: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``P_D^T Y`` from only those detectors' rows."""
        det = np.asarray(detectors).ravel()
        y = np.asarray(counts, dtype=self.dtype).reshape(det.size, self.n_time)
        out = np.zeros(self.n_sky, dtype=self.dtype)
        for k, d in enumerate(det):
            out += y[k] @ self.matrix[d]
        return out

    def block(
        self, t: tuple[int, int] | None = None, n: tuple[int, int] | None = None
    ) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]`` (a view of :attr:`matrix`; ``None`` = whole axis)."""
        (t0, t1), (n0, n1) = block_ranges(t, n, self.n_time, self.n_sky)
        return self.matrix[:, t0:t1, n0:n1]

    def columns(self, pixels: Any) -> np.ndarray:
        """``P[:, :, pixels]`` (a copy of those columns of :attr:`matrix`)."""
        return self.matrix[:, :, self._check_pixels(pixels)]

    def materialise(self) -> MaterialisedResponse:
        """This response (it is in memory already)."""
        return self


def _squared_block(p: np.ndarray, block: Block, y: np.ndarray) -> np.ndarray:
    """``sum_{d, t} P^2 Y`` of one block of ``P`` (the reduce of :meth:`adjoint_squared`'s
    block walk: on a Dask worker only the block's pixels travel back)."""
    (t0, t1), _ = block
    return np.einsum("dtn,dt->n", np.square(p, dtype=np.float64), y[:, t0:t1])


def _check_sizes(shape: tuple[int, ...], fields: dict[str, Any]) -> None:
    """Refuse metadata whose sizes are not those of a matrix of ``shape``."""
    n_det, n_time, n_sky = (int(v) for v in shape)
    inst, grid, tb = fields.get("instrument"), fields.get("grid"), fields.get("time_bins")
    if inst is not None and len(inst.detectors) != n_det:
        raise ParameterError(f"instrument has {len(inst.detectors)} detectors but the "
                             f"response has n_det = {n_det}")
    if grid is not None and int(grid.size) != n_sky:
        raise ParameterError(f"grid has {grid.size} pixels but the response has n_sky = {n_sky}")
    if tb is not None and tb.n_bins != n_time:
        raise ParameterError(f"time_bins has {tb.n_bins} bins but the response has "
                             f"n_time = {n_time}")


def _products(
    p: np.ndarray, blk: Block, sky: np.ndarray | None, counts: np.ndarray | None
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Partial ``P_b S_b`` (n_det, bt) and ``P_b^T Y_b`` (bn,) of one block ``p``."""
    (t0, t1), (n0, n1) = blk
    flat = p.reshape(-1, n1 - n0)
    fwd = None if sky is None else (flat @ sky[n0:n1]).reshape(p.shape[0], t1 - t0)
    adj = None if counts is None else counts[:, t0:t1].ravel() @ flat
    return fwd, adj


class BlockwiseResponse(ResponseOperator):
    """A response whose products walk blocks of ``P`` (evaluated or read one at a time).

    Subclasses set :attr:`blocks` (over the distinct bins) and implement :meth:`block`.

    Notes
    -----
    With blocks ``b = (t-range, n-range)``,
    ``forward(S)[:, t_b] += P_b S[n_b]`` and ``adjoint(Y)[n_b] += P_b^T Y[:, t_b]``; the
    partial sums are added in block order, so the result does not depend on where the
    blocks ran.  :meth:`forward_adjoint` computes ``P S`` and ``P^T Y`` in one sweep (one
    evaluation of every block) for algorithms that need both for independent vectors.
    """

    #: Blocks ``((t0, t1), (n0, n1))`` of the products, over the first :attr:`n_distinct`
    #: bins.
    blocks: list[Block]

    def _sweep(
        self, sky: np.ndarray | None, counts: np.ndarray | None
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        h = self.n_distinct
        x = None if sky is None else np.ascontiguousarray(sky, dtype=self.dtype)
        y = None if counts is None else np.ascontiguousarray(counts, dtype=self.dtype)
        if y is not None:
            y = fold_half_turn(y, h)
        fwd = None if x is None else np.zeros((self.n_det, self.n_time), dtype=self.dtype)
        adj = None if y is None else np.zeros(self.n_sky, dtype=self.dtype)
        # Partial products are added in block order (a cluster returns them in any order):
        # those that arrive early wait in ``pending``.
        pending: dict[int, Any] = {}
        nxt = 0
        for i, _, res in iter_blocks(self._source, self.blocks, x, y, reduce=_products,
                                     **self._run_options()):
            pending[i] = res
            while nxt in pending:
                (t0, t1), (n0, n1) = self.blocks[nxt]
                f, a = pending.pop(nxt)
                if fwd is not None:
                    fwd[:, t0:t1] += f
                if adj is not None:
                    adj[n0:n1] += a
                nxt += 1
        if fwd is not None:
            repeat_half_turn(fwd, h)
        return fwd, adj

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        return self._sweep(sky, None)[0]

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        return self._sweep(None, counts)[1]

    def forward_adjoint(self, sky: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(P S, P^T Y)`` in one sweep over the blocks (each block evaluated once).

        Parameters
        ----------
        sky : ndarray, shape (n_sky,)
        counts : ndarray, shape (n_det, n_time)

        Returns
        -------
        (ndarray, ndarray)
            ``forward(sky)`` and ``adjoint(counts)``.
        """
        fwd, adj = self._sweep(self._check_sky(sky), self._check_counts(counts))
        assert fwd is not None and adj is not None
        return fwd, adj
