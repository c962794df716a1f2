"""Image reconstruction: back-projection, MLEM, MART/SMART, SIRT and NCAR behind one interface.

>>> res = reconstruct(response, folded, method="ncar", seed=1)   # doctest: +SKIP
>>> res.image, res.history["chi2_dof"], res.stop_reason            # doctest: +SKIP

Algorithms use only the response's ``forward``, ``adjoint`` and ``sensitivity``.  See
``docs/reconstruction.md``.

Each solver class registers itself in :data:`ALGORITHMS` where it is defined
(:func:`register_algorithm`); the imports below of every solver module, whose classes this
package exports, are what fill the registry.  A new algorithm is one module with a
registered :class:`Reconstructor` subclass, imported here.
"""

from rotmod.reconstruction.algorithms import MART, MLEM, NCAR, OSEM, SIRT, BackProjection
from rotmod.reconstruction.api import reconstruct
from rotmod.reconstruction.base import (
    ALGORITHMS,
    ReconstructionResult,
    Reconstructor,
    StoppingRule,
    get_algorithm,
    register_algorithm,
)
from rotmod.reconstruction.bootstrap import bootstrap_images
from rotmod.reconstruction.data import ForwardModel, PoissonData, as_data
from rotmod.reconstruction.multires import Refinement, coarse_to_fine
from rotmod.reconstruction.sgp import SGP, Sparse, select_weight, thin_counts
from rotmod.reconstruction.stats import chi2, deviance, log_likelihood

__all__ = [
    "ALGORITHMS",
    "MART",
    "MLEM",
    "NCAR",
    "OSEM",
    "SGP",
    "SIRT",
    "BackProjection",
    "ForwardModel",
    "PoissonData",
    "ReconstructionResult",
    "Reconstructor",
    "Refinement",
    "Sparse",
    "StoppingRule",
    "as_data",
    "bootstrap_images",
    "chi2",
    "coarse_to_fine",
    "deviance",
    "get_algorithm",
    "log_likelihood",
    "reconstruct",
    "register_algorithm",
    "select_weight",
    "thin_counts",
]
