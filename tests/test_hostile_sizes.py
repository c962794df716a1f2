"""Hostile sizes (issue 25, class 2): every request whose memory or time grows with a number
the user chose is estimated and refused *before* the work starts, fast, naming the parameter
and giving the estimate (rotmod.limits: check_memory, check_time)."""

from __future__ import annotations

import logging
import os
import re
import time

import numpy as np
import pytest

from rotmod import Instrument
from rotmod.cli import main
from rotmod.design import scan_designs
from rotmod.limits import (
    RATES,
    MemoryBudgetError,
    TimeBudgetError,
    check_time,
    format_size,
    time_budget,
)
from rotmod.montecarlo import simulate_observation, simulate_profiles
from rotmod.reconstruction import bootstrap_images, reconstruct
from rotmod.response import RadonResponse, build_response
from rotmod.sky import Attitude, AttitudeTable, HealpixGrid, PointSources, SkyGrid

#: A refusal is arithmetic on the sizes (plus, for the Radon table, a few-ms sample of its
#: values): well under a second even on a loaded 2-core CI machine.
FAST = 1.0

#: An estimate in a message: a number and a unit of time or memory.
ESTIMATE = r"(would take about [\d.]+ ?(s|ms|m|hr|d|years)|needs about [\d.]+ [KMGTPE]i?B)"


def _refused(fn, error, match):
    t0 = time.perf_counter()
    with pytest.raises(error) as info:
        fn()
    elapsed = time.perf_counter() - t0
    msg = str(info.value)
    assert re.search(match, msg), msg
    assert re.search(ESTIMATE, msg), msg
    assert elapsed < FAST, f"refused after {elapsed:.2f} s"
    return msg


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


# --- rotmod design --------------------------------------------------------------------------

_DESIGN = dict(detector_diameter=4.0, height=100.0, slat_width=[4.0], slat_gap=[4.0],
               thickness=2.0, energies=[662.0])


@pytest.mark.parametrize(
    ("sizes", "error", "match"),
    [
        # 1e9 angles x 12 sources: 447 GiB; this used to allocate 23 GB and run 52 s first.
        ({"n_angles": 10**9}, MemoryBudgetError, r"n_angles = 1000000000 angles"),
        # 1e12 sources: a bare MemoryError from the meshgrid before.
        ({"n_theta": 10**6, "n_phi": 10**6}, MemoryBudgetError,
         r"n_theta x n_phi = 1000000 x 1000000 sources"),
        # Fits in memory (8 MB of profiles) but 1e6 angles x 1e4 designs of work: hours.
        ({"n_angles": 10**5, "slat_width": np.linspace(1, 8, 100),
          "slat_gap": np.linspace(1, 8, 100)}, TimeBudgetError, r"10000 designs"),
    ],
)
def test_design_sizes_are_refused_before_any_work(sizes, error, match) -> None:
    _refused(lambda: scan_designs(**{**_DESIGN, **sizes}), error, match)


def test_design_cli_angles_and_rings(capsys, tmp_path) -> None:
    for argv in (["--angles", "1e9"], ["--rings", "1e6", "--azimuths", "1e6"]):
        code, err = _cli(capsys, "design", *argv, "-o", tmp_path / "d.ecsv")
        assert code == 2 and "Traceback" not in err, err
        assert re.search(r"design scan of .* needs about [\d.]+ [GTP]iB of memory", err), err
    assert not list(tmp_path.iterdir())


# --- attitude pieces --------------------------------------------------------------------------


def test_attitude_intervals_are_counted_before_they_are_made() -> None:
    # A table covering the spans asked for (outside its samples it refuses first).
    att = AttitudeTable([0.0, 1e300], [0.0, 1.0], [0.0, 1.0], [0.0, 0.0])
    # 1e12 pieces: was a bare MemoryError from linspace; 340 B each, measured.
    msg = _refused(lambda: att.intervals(0, 1e9, 1e-3), MemoryBudgetError,
                   r"max_step = 1e\+09 s / 0.001 s = 1e\+12 attitude pieces")
    assert "TiB" in msg
    # 1e7 pieces fit in memory (3.4 GB is under half of most machines) but take hours at
    # ~600 pieces/s: refused for time, with the way to allow it.
    msg = _refused(lambda: att.intervals(0, 1e4, 1e-3), TimeBudgetError, r"1e\+07 attitude")
    assert "--time-budget" in msg and "ROTMOD_TIME_BUDGET" in msg
    # A step so small that the count overflows a float: refused, with a finite message.
    with pytest.raises(MemoryBudgetError, match=r"inf attitude pieces needs about >1e308 B"):
        att.intervals(0, 1e300, 1e-300)


# --- Monte Carlo photons ---------------------------------------------------------------------


def test_monte_carlo_photons_are_budgeted() -> None:
    inst = Instrument.paper()
    msg = _refused(lambda: simulate_profiles(inst, [6.0], [0.0], np.arange(360.0),
                                             energy=662, n_photons=10**10),
                   TimeBudgetError, r"n_photons = 10000000000 photons in each of 360 cells")
    # The estimate is the photons over the stated rate: 3.6e12 / RATES["mc_photons"].
    hours = 3.6e12 / RATES["mc_photons"] / 3600
    assert re.search(rf"about {int(hours)}hr", msg), msg
    src = PointSources([3.0], [0.0], rate=1e6, energy=122.0)
    _refused(lambda: simulate_observation(inst, src, t_stop=1e6, seed=1),
             MemoryBudgetError, r"an observation of 1e\+06 s at 1e\+06 photons/s")


def test_profile_cli_mc_photons(capsys, tmp_path) -> None:
    code, err = _cli(capsys, "profile", "-s", "6,0", "--mc-photons", "1e10",
                     "-o", tmp_path / "p.csv")
    assert code == 2 and "Traceback" not in err, err
    assert re.search(r"n_photons = 10000000000 .* would take about \d+hr", err), err
    assert not (tmp_path / "p.csv").exists()


def test_the_time_budget_option_is_applied_and_checked(capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.delenv("ROTMOD_TIME_BUDGET", raising=False)
    # 360 cells x 1000 photons: ~8 ms of work, more than a 1 ms budget.
    code, err = _cli(capsys, "profile", "-s", "6,0", "--mc-photons", "1000",
                     "--time-budget", "1ms", "-o", tmp_path / "p.csv")
    assert code == 2 and "time budget of 1.00 ms" in err, err
    assert "ROTMOD_TIME_BUDGET" not in os.environ  # set for the command only
    code, err = _cli(capsys, "profile", "-s", "6,0", "--time-budget", "soon",
                     "-o", tmp_path / "p.csv")
    assert code == 2 and "--time-budget or ROTMOD_TIME_BUDGET" in err and "'soon'" in err, err
    assert not (tmp_path / "p.csv").exists()
    monkeypatch.setenv("ROTMOD_TIME_BUDGET", "2h")
    assert time_budget() == 7200.0
    monkeypatch.setenv("ROTMOD_TIME_BUDGET", "inf")
    assert time_budget() == np.inf


def test_check_time_announces_long_estimates(caplog, monkeypatch) -> None:
    monkeypatch.delenv("ROTMOD_TIME_BUDGET", raising=False)
    with caplog.at_level(logging.INFO, logger="rotmod.limits"):
        # 120 s at 1 unit/s: within the hour, above the 30 s announcement threshold.
        assert check_time(120, 1.0, "a test request", unit="units") == 120.0
        check_time(1, 1.0, "a short request", unit="units")
    assert [r.getMessage() for r in caplog.records] == [
        "a test request: estimated 120.00 s (120 units at ~1/s)"]


# --- bootstrap replicas ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def small():
    inst = Instrument.paper()
    resp = build_response(inst, SkyGrid((3, 3), 1.0), 12, energy=122)
    counts = np.random.default_rng(3).poisson(50.0 * resp.forward(np.ones(9)) + 5.0)
    return resp, counts


def test_bootstrap_replicas_are_refused_before_the_main_run(small, monkeypatch) -> None:
    resp, counts = small
    # 1e9 replicas of 9 pixels: 134 GiB of images, refused before even the main run.
    _refused(lambda: reconstruct(resp, counts, "mlem", uncertainty="bootstrap", n_boot=10**9),
             MemoryBudgetError, r"n_boot = 1000000000 replicas of 9 pixels")
    # For time, the main run's wall time is the measured rate: a budget of 1 ms refuses
    # 1e5 replicas after the main run, before the first replica.
    monkeypatch.setenv("ROTMOD_TIME_BUDGET", "1ms")
    _refused(lambda: reconstruct(resp, counts, "mlem", uncertainty="bootstrap", n_boot=10**5,
                                 max_iter=5), TimeBudgetError, r"n_boot = 100000 replicas")
    # bootstrap_images alone measures its first replica and refuses the rest.
    _refused(lambda: bootstrap_images(resp, counts, "mlem", n_boot=10**5, max_iter=5),
             TimeBudgetError, r"n_boot = 99999 replicas")


def test_reconstruct_cli_uncertainty(capsys, small, tmp_path) -> None:
    from rotmod.events import FoldedProfiles
    from rotmod.io import write_folded
    from rotmod.response import save_response

    resp, counts = small
    folded = FoldedProfiles(counts, np.full(12, 10.0), 12, resp.instrument, [[0.0, 120.0]])
    write_folded(folded, tmp_path / "f.fits")
    save_response(tmp_path / "r.zarr", resp)
    code, err = _cli(capsys, "reconstruct", tmp_path / "f.fits", tmp_path / "r.zarr",
                     "-o", tmp_path / "i.fits", "--uncertainty", "1e9")
    assert code == 2 and "Traceback" not in err, err
    assert re.search(r"n_boot = 1000000000 replicas .* needs about [\d.]+ GiB", err), err
    assert not (tmp_path / "i.fits").exists()


# --- the Radon table and HEALPix grids -------------------------------------------------------


def test_a_radon_table_near_the_horizon_is_estimated_before_it_is_made(monkeypatch) -> None:
    inst = Instrument.paper()
    RadonResponse(inst, SkyGrid((3, 3), 1.0), 12, 122)  # compiles the kernels first
    # `rotmod response --operator radon --fov 179`: pixels 66 deg from the axis make the
    # table from 1169 x 2124 x 10 profile values, estimated at ~16 s here (1125 x 31027 x 10,
    # ~150-250 s measured, before the table was built from nodes in the shadow's shift).
    # A 1 s budget refuses it whatever the machine's speed within a factor of 16.
    monkeypatch.setenv("ROTMOD_TIME_BUDGET", "1s")
    msg = _refused(lambda: RadonResponse(inst, SkyGrid.square(179, 2.0), 64, 122),
                   TimeBudgetError, r"a Radon table from 1169 x \d+ x \d+ profile values")
    assert re.search(r"pixels up to 6\d\.\d+ deg from the axis", msg), msg


def test_radon_cli_fov_179_is_refused_over_a_small_budget(capsys, tmp_path) -> None:
    code, err = _cli(capsys, "response", "--operator", "radon", "--fov", "179", "--pixel", "2",
                     "--time-budget", "1s", "-o", tmp_path / "r.zarr")
    assert code == 2 and "Traceback" not in err, err
    assert re.search(r"Radon table .* would take about .* time budget of 1\.00 s", err), err
    assert not list(tmp_path.iterdir())


def test_a_response_matrix_is_estimated_before_it_is_computed(capsys, tmp_path,
                                                               monkeypatch) -> None:
    # 1 x 360 bins x 490000 pixels of the exact model: ~40-100 s here (the 78400-pixel store
    # took 35-39 s, load 9), refused over a 1 s budget after the pixels' projection (0.4 s).
    code, err = _cli(capsys, "response", "--fov", "14", "--pixel", "0.02", "--time-budget",
                     "1s", "-o", tmp_path / "r.zarr")
    assert code == 2 and "Traceback" not in err, err
    assert re.search(r"a response of 1 detector\(s\) x 360 time bins x 490000 pixels \(exact "
                     r"model, 1 sub-sample\(s\) per bin\) would take about", err), err
    assert not list(tmp_path.iterdir())  # no store, no .partial, no lock
    monkeypatch.setenv("ROTMOD_TIME_BUDGET", "1s")
    build_response(Instrument.paper(), SkyGrid((3, 3), 1.0), 12, energy=122)  # fits
    with pytest.raises(TimeBudgetError, match=r"x 78400 pixels .* would take about"):
        build_response(Instrument.paper(), SkyGrid.square(14, 0.05), 1440, energy=122)


def test_a_huge_nside_gives_a_finite_estimate() -> None:
    msg = _refused(lambda: HealpixGrid(2**29, 0.0, 0.0, 5.0, Attitude(0.0, 0.0)),
                   MemoryBudgetError, r"HEALPix nside 536870912 pixels within 5 deg")
    # 12 nside^2 sin^2(2.5 deg) pixels x 80 B = 5.3e20 B = 468 PiB (was "inf PiB").
    n = 12.0 * 4.0**29 * np.sin(np.radians(2.5)) ** 2
    assert f"needs about {format_size(80 * n)}" in msg and "inf" not in msg
    assert format_size(80 * n).endswith("PiB")
