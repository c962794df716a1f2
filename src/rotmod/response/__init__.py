"""The response: a linear operator from sky to folded counts (``O = P S``).

* :class:`ResponseSpec` -- what a response is computed for (instrument, grid, time binning,
  model, energy, distance, dtype), validated once; every operator and writer takes one
  (or its fields, from which it builds one);
* :class:`TimeBinning` -- mask-angle bins per rotation (bin centre or bin average);
* :func:`build_response` -- compute ``P[d, t, n]`` with any profile model and hold it in
  memory as a :class:`MaterialisedResponse`;
* :class:`MatrixFreeResponse` -- the same operator computing blocks of ``P`` on the fly;
* :class:`RadonResponse` -- the exact model factorised through one table and a Radon
  projection of the sky: products cost ``n_sky`` work per angle, not ``n_det n_sky``
  profile evaluations (wide fields);
* :func:`write_response` / :func:`save_response` / :func:`open_response` -- responses on
  disk (zarr, :mod:`rotmod.io.response_store`), computed in blocks (locally or on a Dask
  cluster, :mod:`rotmod.response.parallel`) and read lazily;
* :class:`UnfoldedResponse` -- the response to counts in short time bins of a window
  (not folded), with a transient's light curve and the attitude at each bin: a burst's
  likelihood.

Reconstruction sees only :class:`ResponseOperator` (``forward``, ``adjoint``,
``sensitivity``, ``as_linear_operator``); every operator gives its values with
:meth:`~ResponseOperator.materialise` and any block of them with
:meth:`~ResponseOperator.block`.
"""

from rotmod.binning import TimeBinning
from rotmod.response.materialised import MaterialisedResponse, build_response
from rotmod.response.matrix_free import MatrixFreeResponse
from rotmod.response.operator import ResponseOperator
from rotmod.response.radon import RadonResponse
from rotmod.response.spec import ResponseSpec
from rotmod.response.stored import (
    STORE_KINDS,
    StoredResponse,
    load_response,
    open_response,
    save_response,
)
from rotmod.response.unfolded import UnfoldedResponse, aligned_edges
from rotmod.response.writer import write_response

__all__ = [
    "STORE_KINDS",
    "MaterialisedResponse",
    "MatrixFreeResponse",
    "RadonResponse",
    "ResponseOperator",
    "ResponseSpec",
    "StoredResponse",
    "TimeBinning",
    "UnfoldedResponse",
    "aligned_edges",
    "build_response",
    "load_response",
    "open_response",
    "save_response",
    "write_response",
]
