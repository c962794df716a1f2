"""Disk budgets: a store the free space cannot hold is refused before any work."""

from __future__ import annotations

import shutil
from collections import namedtuple

import numpy as np
import pytest

from rotmod.limits import DiskSpaceError, check_disk, free_disk
from rotmod.response import RadonResponse, build_response, save_response, write_response
from rotmod.response import writer as writer_module
from rotmod.sky import SkyGrid

_Usage = namedtuple("_Usage", "total used free")


@pytest.fixture
def free_space(monkeypatch):
    """Set the free space every disk check sees (bytes); returns the paths it was asked."""
    asked = []

    def set_free(nbytes):
        def disk_usage(path):
            asked.append(path)
            return _Usage(10 * nbytes, 9 * nbytes, nbytes)

        monkeypatch.setattr(shutil, "disk_usage", disk_usage)
        return asked

    return set_free


def test_check_disk_names_estimate_free_space_and_path(tmp_path, free_space):
    asked = free_space(2**20)
    check_disk(2**20, tmp_path / "new" / "a.zarr", "a store")  # fits exactly
    # The nearest existing folder is asked: the store and its parent need not exist.
    assert asked == [tmp_path]
    with pytest.raises(DiskSpaceError, match=(r"a store needs up to 1\.50 MiB of disk "
                                              r"\(uncompressed\), more than the 1\.00 MiB free "
                                              r"at '.*a\.zarr'; use less")):
        check_disk(1.5 * 2**20, tmp_path / "a.zarr", "a store", hint="use less")
    assert free_disk(tmp_path) == 2**20


def test_write_response_refuses_before_any_work(tmp_path, inst, free_space, monkeypatch):
    grid = SkyGrid((6, 7), 1.0)
    need = 7 * 20 * 42 * 4  # detectors x bins x pixels x float32
    free_space(need // 2)

    def no_plan(spec):
        raise AssertionError("the plan was computed before the disk check")

    monkeypatch.setattr(writer_module, "make_plan", no_plan)
    with pytest.raises(DiskSpaceError, match=(
            r"a response store of 7 detector\(s\) x 20 time bins x 42 pixels float32 needs up "
            r"to 22\.97 kiB of disk \(uncompressed\), more than the 11\.48 kiB free at "
            r"'.*w\.zarr'; use larger pixels or a smaller field, fewer time bins")):
        write_response(tmp_path / "w.zarr", inst, grid, 20)
    assert list(tmp_path.iterdir()) == []  # no store, no .partial, no lock
    monkeypatch.undo()
    free_space(need)
    assert write_response(tmp_path / "w.zarr", inst, grid, 20).n_sky == 42


def test_a_resumed_store_needs_only_what_it_lacks(tmp_path, inst, free_space):
    grid = SkyGrid((6, 7), 1.0)
    path, partial = tmp_path / "r.zarr", tmp_path / "r.zarr.partial"

    def stop(done, total):
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_response(path, inst, grid, 20, chunks=(4, 21), on_chunk=stop)
    written = sum(f.stat().st_size for f in partial.rglob("*") if f.is_file())
    assert written > 0
    need = 7 * 20 * 42 * 4
    free_space(need - written)
    assert write_response(path, inst, grid, 20).n_time == 20


def test_save_response_budgets_what_each_kind_stores(tmp_path, inst, free_space):
    grid = SkyGrid((6, 7), 1.0)
    dense = build_response(inst, grid, 20, "exact")
    free_space(dense.matrix.nbytes - 1)
    with pytest.raises(DiskSpaceError, match=r"7 detector\(s\) x 20 time bins x 42 pixels float32"):
        save_response(tmp_path / "d.zarr", dense)
    assert list(tmp_path.iterdir()) == []
    # A Radon store holds its table (far smaller than P for a real field).
    radon = RadonResponse(inst, grid, 20, dtype=np.float32)
    free_space(radon.table.nbytes - 1)
    with pytest.raises(DiskSpaceError, match=r"a Radon response store \(a table of \d+ x \d+ "
                                             r"float32\).*raise tolerance"):
        save_response(tmp_path / "radon.zarr", radon)
    free_space(radon.table.nbytes)
    save_response(tmp_path / "radon.zarr", radon)
