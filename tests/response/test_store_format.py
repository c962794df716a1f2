"""Response stores read by other tools: xarray sees named dimensions, coordinates with units
and attributes in words; stores in the layout written before those additions still open."""

from __future__ import annotations

import datetime
import json
import shutil

import numpy as np
import pytest
import zarr

from rotmod.io import response_store as fmt
from rotmod.response import (
    RadonResponse,
    TimeBinning,
    build_response,
    open_response,
    save_response,
    write_response,
)
from rotmod.sky import Attitude, CelestialGrid, HealpixGrid, SkyGrid

xr = pytest.importorskip("xarray")

_UNITS = {"mask_angle": "deg", "detector_x": "cm", "detector_y": "cm", "theta": "deg",
          "phi": "deg", "ra": "deg", "dec": "deg", "pixel_y": "1", "pixel_x": "1",
          "healpix_index": "1"}


def _check_axes(ds, resp):
    """The dimensions, coordinates (values and units) every dense store has."""
    assert ds["P"].dims == ("detector", "time_bin", "pixel")
    assert ds.sizes == {"detector": resp.n_det, "time_bin": resp.n_time, "pixel": resp.n_sky}
    assert ds["P"].attrs["units"] == "1" and "characteristic profile" in ds["P"].attrs["long_name"]
    np.testing.assert_array_equal(ds["P"].values, resp.materialise().matrix)
    for name, coord in ds.coords.items():
        assert coord.attrs["units"] == _UNITS[name] and coord.attrs["long_name"], name
    np.testing.assert_array_equal(ds["mask_angle"], np.degrees(resp.time_bins.angles()))
    np.testing.assert_array_equal(ds["detector_x"], resp.instrument.detectors.positions[:, 0])
    np.testing.assert_array_equal(ds["detector_y"], resp.instrument.detectors.positions[:, 1])
    theta, phi = resp.grid.directions()
    np.testing.assert_array_equal(ds["theta"], theta.to_value("deg"))
    np.testing.assert_array_equal(ds["phi"], phi.to_value("deg"))


def test_xarray_opens_a_dense_store(tmp_path, inst):
    grid = SkyGrid((6, 7), 1.0)
    path = tmp_path / "r.zarr"
    resp = write_response(path, inst, grid, TimeBinning(20, "average", 2), energy=511.0)
    ds = xr.open_zarr(path)  # no warning: the metadata is consolidated
    _check_axes(ds, resp)
    assert {"ra", "dec", "healpix_index"}.isdisjoint(ds.coords)  # an instrument-frame grid
    # Every pixel's image row and column: the sky axis unstacks into images.
    img = ds["P"].set_index(pixel=["pixel_y", "pixel_x"]).unstack("pixel")
    assert img.sizes["pixel_y"] == 6 and img.sizes["pixel_x"] == 7
    np.testing.assert_array_equal(img.values, resp.materialise().matrix.reshape(7, 20, 6, 7))
    assert ds.attrs["energy"] == "511 keV" and ds.attrs["model"] == "exact"
    assert ds.attrs["source_distance"] == "infinity" and ds.attrs["dtype"] == "float32"
    assert ds.attrs["time_bins"].startswith("20 mask-angle bins per rotation, mode 'average'")
    assert ds.attrs["sky_grid"].startswith("instrument grid (SkyGrid) of 42 pixels (6 x 7)")
    assert "7 detector(s)" in ds.attrs["instrument"] and "lead" in ds.attrs["instrument"]
    # When and from which code, as every FITS product says it.
    created = datetime.datetime.fromisoformat(ds.attrs["date_created"])
    assert abs(datetime.datetime.now(datetime.UTC) - created).total_seconds() < 600
    assert ds.attrs["rotmod_commit"]
    # The JSON metadata rotmod reads is still there, unchanged.
    assert json.loads(ds.attrs["rotmod_response"])["format_version"] == fmt.FORMAT_VERSION


def test_stores_on_the_sky_carry_ra_dec(tmp_path, inst):
    att = Attitude(200.0, 40.0, 25.0)
    grids = {"cel": CelestialGrid((5, 7), 0.5, 200.0, 40.0, att),
             "hpx": HealpixGrid(256, 200.0, 40.0, 1.0, att)}
    for name, grid in grids.items():
        resp = save_response(tmp_path / f"{name}.zarr",
                             build_response(inst, grid, 12, "advanced-approx"))
        ds = xr.open_zarr(tmp_path / f"{name}.zarr")
        _check_axes(ds, resp)
        c = grid.sky_coords()
        np.testing.assert_array_equal(ds["ra"], c.ra.deg)
        np.testing.assert_array_equal(ds["dec"], c.dec.deg)
        assert ds["ra"].attrs["long_name"].endswith("(ICRS)")
        # Image rows and columns for the WCS grid, HEALPix indices for the HEALPix grid.
        assert ("pixel_x" in ds.coords) == (name == "cel")
        assert ("healpix_index" in ds.coords) == (name == "hpx")
    np.testing.assert_array_equal(ds["healpix_index"], grids["hpx"].pixels)


def test_xarray_opens_a_radon_store(tmp_path, inst):
    grid = SkyGrid((6, 7), 1.0)
    radon = RadonResponse(inst, grid, 20, energy=662.0)
    save_response(tmp_path / "radon.zarr", radon)
    ds = xr.open_zarr(tmp_path / "radon.zarr")
    assert ds["table"].dims == ("detector_offset", "direction_node")
    np.testing.assert_array_equal(ds["table"].values, radon.table)
    assert ds["table"].attrs["units"] == "1"
    # The operator's axes are described too (their own variables: no P to attach them to).
    np.testing.assert_array_equal(ds["mask_angle"], np.degrees(radon.time_bins.angles()))
    assert ds["theta"].dims == ("pixel",) and ds["theta"].size == 42
    assert ds.attrs["operator"].startswith("radon (tolerance 0.0001")


def _as_old_layout(path):
    """Rewrite a store as rotmod wrote it before the axes were described: P without
    dimension names or attributes, no coordinate arrays, no consolidated metadata, only the
    JSON metadata and "complete" on the group."""
    keep = {"P", "table"}
    for sub in path.iterdir():
        if sub.is_dir() and sub.name not in keep:
            shutil.rmtree(sub)
    for meta_file in [path / "zarr.json", *(path / k / "zarr.json" for k in keep)]:
        if not meta_file.exists():
            continue
        d = json.loads(meta_file.read_text())
        d.pop("consolidated_metadata", None)
        d.pop("dimension_names", None)
        attrs = d.get("attributes", {})
        d["attributes"] = {k: attrs[k] for k in ("rotmod_response", "complete") if k in attrs}
        meta_file.write_text(json.dumps(d))


def test_a_store_in_the_old_layout_still_opens(tmp_path, inst):
    grid = SkyGrid((6, 7), 1.0)
    ref = build_response(inst, grid, 20, "advanced-approx")
    path = tmp_path / "old.zarr"
    save_response(path, ref, chunks=(6, 20))
    _as_old_layout(path)
    g = zarr.open_group(str(path), mode="r", use_consolidated=False)
    assert sorted(g.keys()) == ["P"] and g["P"].metadata.dimension_names is None
    old = open_response(path, instrument=inst, grid=grid, time_bins=20)
    np.testing.assert_array_equal(old.materialise().matrix, ref.matrix)
    # Saved again, it gets the new layout.
    new = save_response(tmp_path / "new.zarr", old)
    assert xr.open_zarr(tmp_path / "new.zarr")["P"].dims == fmt.DIMS
    assert new.metadata() == old.metadata()
