"""Response storage: round trip, mismatch refusal, atomic and resumable writes."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rotmod import DetectorArray, Instrument
from rotmod.errors import InstrumentMismatchError, ParameterError, RotmodError
from rotmod.materials import PAPER_SIGMA_662
from rotmod.response import (
    StoredResponse,
    TimeBinning,
    build_response,
    load_response,
    open_response,
    save_response,
    write_response,
)
from rotmod.sky import SkyGrid


@pytest.fixture(scope="module")
def grid():
    return SkyGrid((6, 7), 1.0)


@pytest.fixture(scope="module")
def ref(inst, grid):
    return build_response(inst, grid, 20, "advanced-approx")


def test_save_load_round_trip(tmp_path, inst, grid, ref):
    path = tmp_path / "r.zarr"
    stored = save_response(path, ref, chunks=(6, 20))
    assert isinstance(stored, StoredResponse)
    assert stored.array.chunks == (7, 6, 20)
    loaded = load_response(path, instrument=inst, grid=grid, time_bins=20,
                           model="advanced-approx")
    np.testing.assert_array_equal(loaded.matrix, ref.matrix)
    assert loaded.matrix.dtype == np.float32
    assert loaded.instrument == inst and loaded.grid == grid
    assert loaded.time_bins == TimeBinning(20)
    assert loaded.model.describe() == ref.model.describe()
    md = stored.metadata()
    assert md["instrument"] == inst.to_dict() and md["rotmod_version"]
    # The lazy operator streams chunks; float32 sums in another order: ~1e-6 relative.
    x = np.random.default_rng(0).random(42)
    np.testing.assert_allclose(stored.forward(x), ref.forward(x), rtol=1e-5)
    y = np.random.default_rng(1).random((7, 20))
    np.testing.assert_allclose(stored.adjoint(y), ref.adjoint(y), rtol=1e-5)


def test_overwrite(tmp_path, ref):
    path = tmp_path / "r.zarr"
    save_response(path, ref)
    with pytest.raises(ParameterError, match="already exists"):
        save_response(path, ref)
    save_response(path, ref, overwrite=True)
    assert not (tmp_path / "r.zarr.old").exists()


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [
        (
            "instrument.mask.thickness",
            {"instrument": Instrument(
                Instrument.paper(h=2.5, sigma=PAPER_SIGMA_662).mask,
                DetectorArray.hexagonal(3.8, rings=1),
            )},
        ),
        ("grid.pixel_size", {"grid": SkyGrid((6, 7), 1.1)}),
        ("time_bins.n_bins", {"time_bins": 21}),
        ("time_bins.mode", {"time_bins": TimeBinning(20, "average")}),
        ("model.model", {"model": "exact"}),
        ("energy", {"energy": 511.0}),
    ],
)
def test_mismatch_refused(tmp_path, ref, field, kwargs):
    path = tmp_path / "r.zarr"
    save_response(path, ref)
    with pytest.raises(InstrumentMismatchError, match=field.replace(".", r"\.")):
        open_response(path, **kwargs)


def test_detector_mismatch_named(tmp_path, inst, ref):
    path = tmp_path / "r.zarr"
    save_response(path, ref)
    other = Instrument(inst.mask, DetectorArray.hexagonal(3.8, rings=1, pitch=4.2))
    with pytest.raises(InstrumentMismatchError, match=r"instrument\.detectors\.positions"):
        open_response(path, instrument=other)


class Interrupt(RuntimeError):
    pass


def test_interrupted_write_resumes(tmp_path, inst, grid):
    path = tmp_path / "w.zarr"
    partial = tmp_path / "w.zarr.partial"
    full = build_response(inst, grid, TimeBinning(20, "average", 2))
    seen = []

    def stop_after_3(done, total):
        seen.append(done)
        if done == 3:
            raise Interrupt("stop")

    with pytest.raises(Interrupt):
        write_response(path, inst, grid, TimeBinning(20, "average", 2), chunks=(4, 20),
                       on_chunk=stop_after_3)
    # Nothing at the final name; the half-written store is refused by the readers.
    assert not path.exists() and partial.exists()
    with pytest.raises(ParameterError, match="unfinished"):
        open_response(path)
    with pytest.raises(ParameterError, match="must not end with"):
        open_response(partial)
    # Resuming with other inputs is refused, naming the field.
    with pytest.raises(InstrumentMismatchError, match=r"time_bins\.n_sub"):
        write_response(path, inst, grid, TimeBinning(20, "average", 3), chunks=(4, 20))
    resumed = []
    out = write_response(path, inst, grid, TimeBinning(20, "average", 2),
                         on_chunk=lambda d, t: resumed.append(d))
    # 5 x 3 = 15 chunks: 3 done before the interruption, 12 computed on resume.
    assert resumed == list(range(4, 16))
    assert not partial.exists()
    # Chunked vs one-call evaluation: the kernels may round the last float64 bit
    # differently (SIMD lanes), which can flip one float32 ulp (<= 6e-8 for values <= 1).
    np.testing.assert_allclose(out.materialise().matrix, full.matrix, rtol=0, atol=6e-8)


def test_write_response_matches_build(tmp_path, inst, grid, ref):
    out = write_response(tmp_path / "a.zarr", inst, grid, 20, "advanced-approx", progress=False)
    np.testing.assert_allclose(out.materialise().matrix, ref.matrix, rtol=0, atol=6e-8)  # as above
    with pytest.raises(ParameterError, match="already exists"):
        write_response(tmp_path / "a.zarr", inst, grid, 20)


def test_open_errors(tmp_path):
    with pytest.raises(ParameterError, match="does not exist"):
        open_response(tmp_path / "nothing.zarr")
    import zarr

    zarr.open_group(str(tmp_path / "other.zarr"), mode="w")
    with pytest.raises(ParameterError, match="not a rotmod response store"):
        open_response(tmp_path / "other.zarr")


def _chunk_files(store):
    return sorted(p for p in (store / "P" / "c").rglob("*") if p.is_file())


def test_a_deleted_chunk_in_a_partial_store_is_recomputed(tmp_path, inst, grid):
    path, partial = tmp_path / "d.zarr", tmp_path / "d.zarr.partial"
    tb = TimeBinning(20)

    def stop_after_3(done, total):
        if done == 3:
            raise Interrupt("stop")

    with pytest.raises(Interrupt):
        write_response(path, inst, grid, tb, chunks=(4, 20), on_chunk=stop_after_3)
    victim = _chunk_files(partial)[0]
    victim.unlink()  # marked done, but gone
    resumed = []
    out = write_response(path, inst, grid, tb, on_chunk=lambda d, t: resumed.append(d))
    assert len(resumed) == 13  # 12 never written + the deleted one
    m = out.materialise().matrix
    import zarr

    assert np.all(np.isfinite(m)) and zarr.open_group(str(path)).attrs["complete"] is True
    np.testing.assert_allclose(m, build_response(inst, grid, tb).matrix, rtol=0, atol=6e-8)


@pytest.mark.parametrize("damage", ["flip", "truncate", "delete"])
def test_a_damaged_chunk_is_an_error_naming_store_and_chunk(tmp_path, inst, grid, damage):
    path = tmp_path / "x.zarr"
    write_response(path, inst, grid, 20, chunks=(10, 42))
    f = _chunk_files(path)[1]
    data = bytearray(f.read_bytes())
    if damage == "flip":
        data[len(data) // 2] ^= 0x04
        f.write_bytes(bytes(data))
    elif damage == "truncate":
        f.write_bytes(bytes(data[: len(data) // 2]))
    else:
        f.unlink()
    resp = open_response(path)
    with pytest.raises(RotmodError, match=r"response store .*x\.zarr.*chunk t 10:20, n 0:42"):
        resp.forward(np.ones(resp.n_sky))
    with pytest.raises(RotmodError, match="rebuild it"):
        resp.materialise()


def test_damaged_metadata_is_a_clear_error(tmp_path, inst, grid):
    path = tmp_path / "m.zarr"
    write_response(path, inst, grid, 20)
    (path / "zarr.json").write_text("{not json")
    with pytest.raises(RotmodError, match=r"m\.zarr.* cannot be opened"):
        open_response(path)


def test_a_second_writer_is_refused_and_a_later_run_recovers(tmp_path, inst, grid):
    from rotmod.io.lock import LockedError, PathLock

    path = tmp_path / "l.zarr"
    with PathLock(path), pytest.raises(LockedError, match=rf"pid {os.getpid()}"):
        write_response(path, inst, grid, 20)
    # The lock dies with its holder: the next run goes ahead.
    assert write_response(path, inst, grid, 20).n_time == 20
    # save_response takes the same lock (it would otherwise remove a writer's .partial store).
    with PathLock(path), pytest.raises(LockedError, match=rf"pid {os.getpid()}"):
        save_response(path, build_response(inst, grid, 20), overwrite=True)
    # No lock file is left beside the store.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.zarr"]


def test_every_operator_is_stored_by_its_store_kind(tmp_path, inst, grid, ref):
    from rotmod.response import STORE_KINDS, MatrixFreeResponse, RadonResponse

    assert STORE_KINDS.names() == ("dense", "radon")
    assert ref.store_kind == "dense" and RadonResponse.store_kind == "radon"
    free = MatrixFreeResponse(inst, grid, 20, "advanced-approx", dtype=np.float32)
    a = save_response(tmp_path / "free.zarr", free, chunks=(6, 20))
    b = save_response(tmp_path / "ref.zarr", ref, chunks=(6, 20))
    assert isinstance(a, StoredResponse) and a.spec is not None
    np.testing.assert_array_equal(a.materialise().matrix, b.materialise().matrix)
    # A stored response saves again (its blocks are read from the first store).
    c = save_response(tmp_path / "copy.zarr", b, chunks=(7, 9))
    np.testing.assert_array_equal(c.materialise().matrix, ref.matrix)
    assert c.metadata() == b.metadata()
    with pytest.raises(ParameterError, match="already exists; pass overwrite=True"):
        save_response(tmp_path / "copy.zarr", b)
