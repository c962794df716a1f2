"""Distributed evaluation on a loopback LocalCluster equals the local result."""

from __future__ import annotations

import distributed
import numpy as np
import pytest

from rotmod.errors import ParameterError
from rotmod.response import MatrixFreeResponse, RadonResponse, build_response, write_response
from rotmod.response.parallel import get_client
from rotmod.sky import SkyGrid


@pytest.fixture(scope="module")
def cluster():
    # Workers as threads of this process, but talking TCP on loopback (processes=False alone
    # would use the in-process transport, which rejects host=).  Starts in ~1 s and shares
    # the numba cache; processes=True works the same way but compiles once per worker.
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, host="127.0.0.1",
        protocol="tcp", dashboard_address=None,
    ) as lc, distributed.Client(lc) as client:
        yield lc, client


def test_distributed_equals_local(cluster, tmp_path, inst):
    lc, client = cluster
    grid = SkyGrid((8, 8), 1.0)
    local = build_response(inst, grid, 30, block_size=(7, 25), progress=False)
    dist = build_response(inst, grid, 30, client=client, block_size=(7, 25))
    # Every element comes from the same float64 kernel call on the same inputs: bit for bit.
    np.testing.assert_array_equal(dist.matrix, local.matrix)
    via_addr = build_response(
        inst, grid, 30, scheduler=lc.scheduler_address, block_size=(7, 25)
    )
    np.testing.assert_array_equal(via_addr.matrix, local.matrix)

    mf_local = MatrixFreeResponse(inst, grid, 30, block_size=(7, 25))
    mf_dist = MatrixFreeResponse(inst, grid, 30, block_size=(7, 25), client=client)
    rng = np.random.default_rng(0)
    x, y = rng.random(64), rng.random((7, 30))
    # Partial products are combined in block order on the caller's side: bit for bit.
    np.testing.assert_array_equal(mf_dist.forward(x), mf_local.forward(x))
    np.testing.assert_array_equal(mf_dist.adjoint(y), mf_local.adjoint(y))

    stored = write_response(tmp_path / "d.zarr", inst, grid, 30, client=client, chunks=(7, 25))
    np.testing.assert_array_equal(stored.materialise().matrix, local.matrix)


def test_radon_distributed_equals_local(cluster, inst):
    _, client = cluster
    grid = SkyGrid((9, 8), 0.8)
    local = RadonResponse(inst, grid, 40, dtype=np.float64, block_bins=6)
    dist = RadonResponse(inst, grid, 40, dtype=np.float64, block_bins=6, client=client)
    assert len(local.blocks) == 4
    rng = np.random.default_rng(1)
    x, y = rng.random(72), rng.random((7, 40))
    # Each block of time bins is one task; every kernel sums in an order that does not
    # depend on the threads it runs on, and the caller adds the blocks' partial adjoints in
    # block order: bit for bit.
    np.testing.assert_array_equal(dist.forward(x), local.forward(x))
    np.testing.assert_array_equal(dist.adjoint(y), local.adjoint(y))


def test_client_errors():
    with pytest.raises(ParameterError, match="either scheduler or client"), get_client(
        "tcp://127.0.0.1:1", object()
    ):
        pass
    with pytest.raises(ParameterError, match=r"client must be a distributed\.Client"), \
            get_client(None, object()):
        pass
