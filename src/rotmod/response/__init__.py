"""The response: a linear operator from sky to folded counts (``O = P S``).

* :class:`TimeBinning` -- mask-angle bins per rotation (bin centre or bin average);
* :func:`build_response` -- compute ``P[d, t, n]`` with any profile model and hold it in
  memory as a :class:`MaterialisedResponse`;
* :class:`MatrixFreeResponse` -- the same operator computing blocks of ``P`` on the fly;
* :class:`RadonResponse` -- the exact model factorised through one table and a Radon
  projection of the sky: products cost ``n_sky`` work per angle, not ``n_det n_sky``
  profile evaluations (wide fields);
* :func:`write_response` / :func:`open_response` -- responses on disk (zarr), computed in
  blocks (locally or on a Dask cluster, :mod:`rotmod.response.parallel`) and read lazily.

Reconstruction sees only :class:`ResponseOperator` (``forward``, ``adjoint``,
``sensitivity``, ``as_linear_operator``).
"""

from rotmod.binning import TimeBinning
from rotmod.response.materialised import MaterialisedResponse, build_response
from rotmod.response.matrix_free import MatrixFreeResponse
from rotmod.response.operator import ResponseOperator
from rotmod.response.radon import RadonResponse
from rotmod.response.stored import (
    StoredResponse,
    load_response,
    open_response,
    save_response,
    write_response,
)

__all__ = [
    "MaterialisedResponse",
    "MatrixFreeResponse",
    "RadonResponse",
    "ResponseOperator",
    "StoredResponse",
    "TimeBinning",
    "build_response",
    "load_response",
    "open_response",
    "save_response",
    "write_response",
]
