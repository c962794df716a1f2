"""``rotmod reproduce`` at a tiny size: index.html with every section, summary.png, reruns."""

from __future__ import annotations

import json

import pytest

from rotmod.cli import main
from rotmod.errors import ParameterError
from rotmod.paper.report import reproduce


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro")
    assert main(["reproduce", "--tiny", "--output", str(out)]) == 0
    return out


def test_tiny_reproduce_writes_report(tiny) -> None:
    index = (tiny / "index.html").read_text()
    for section in ('id="profiles"', 'id="speed"', 'id="images"', 'id="prototype"',
                    "summary.png", "Paper:", "rotmod:"):
        assert section in index
    assert "0.8 s" in index and "1.3 days" in index  # the paper's figures beside ours
    assert (tiny / "summary.png").stat().st_size > 10_000
    assert (tiny / "profiles" / "profile_thick20.png").exists()
    speed = json.loads((tiny / "speed" / "result.json").read_text())
    assert {r["model"] for r in speed["rows"]} >= {"standard", "advanced-g0",
                                                   "advanced-approx", "exact", "montecarlo"}
    assert all(r["time_s"] is None or r["time_s"] > 0 for r in speed["rows"])


def test_rerun_skips_finished_steps(tiny) -> None:
    lines: list[str] = []
    reproduce(tiny, size="tiny", steps=["profiles", "speed"], log=lines.append)
    assert any("skipped" in s for s in lines if s.startswith("[profiles]"))
    assert any("skipped" in s for s in lines if s.startswith("[speed]"))


def test_interrupted_step_leaves_no_output(tmp_path, monkeypatch) -> None:
    import rotmod.paper.report as rep

    def interrupted(tmp, *a, **k):
        (tmp / "partial.png").write_text("x")
        raise KeyboardInterrupt

    monkeypatch.setattr(rep, "_step_speed", interrupted)
    with pytest.raises(KeyboardInterrupt):
        reproduce(tmp_path, size="tiny", steps=["speed"])
    assert not (tmp_path / "speed").exists()
    assert not list(tmp_path.glob(".speed.tmp-*"))


def test_bad_size_and_steps(tmp_path) -> None:
    with pytest.raises(ParameterError, match="size must be one of"):
        reproduce(tmp_path, size="huge")
    with pytest.raises(ParameterError, match="steps must be among"):
        reproduce(tmp_path, size="tiny", steps=["nope"])


def test_page_names_its_provenance_and_files_follow_the_umask(tiny) -> None:
    # The fixture ran under the suite's umask; files must be readable like any other file
    # the user creates (tempfile's 0600 would make them private).
    from rotmod.io.atomic import current_umask

    want_file = 0o666 & ~current_umask()
    want_dir = 0o777 & ~current_umask()
    for p in tiny.rglob("*"):
        mode = p.stat().st_mode & 0o777
        assert mode == (want_dir if p.is_dir() else want_file), (p, oct(mode))
    index = (tiny / "index.html").read_text()
    meta = json.loads((tiny / "reproduce.json").read_text())["provenance"]
    assert meta["rotmod"] and meta["libraries"]["numpy"] and meta["seed"] == 1
    assert (meta["git_commit"] or "unknown") in index
    assert meta["libraries"]["numba"] in index
    fits_files = list((tiny / "images").glob("*.fits"))
    assert fits_files and all(f.name in index for f in fits_files)
    from rotmod.io.images import read_image

    img = read_image(fits_files[0])
    assert img.image.ndim == 2 and img.header["BUNIT"]


def test_umask_022_gives_world_readable_files(tmp_path) -> None:
    import os
    import stat

    old = os.umask(0o022)
    try:
        reproduce(tmp_path, size="tiny", steps=["speed"])
    finally:
        os.umask(old)
    for p in [tmp_path / "index.html", tmp_path / "reproduce.json",
              tmp_path / "speed" / "result.json", tmp_path / "speed"]:
        assert p.stat().st_mode & stat.S_IROTH, p


def test_scenarios_and_selections_are_registry_names() -> None:
    from rotmod.paper import selection
    from rotmod.paper.report import SIZES
    from rotmod.paper.scenarios import SCENARIOS, make_scenario
    from rotmod.paper.validation import SCENARIOS as PROFILE_SCENARIOS
    from rotmod.paper.validation import get_scenario
    from rotmod.profiles import MODELS

    assert SCENARIOS.names() == ("a", "b", "c", "d")
    with pytest.raises(ParameterError, match=r"name must be one of .*got 'e'"):
        make_scenario("e")
    assert get_scenario("wide50") is PROFILE_SCENARIOS.get("wide50")
    with pytest.raises(ParameterError, match=r"did you mean 'thick20'\?"):
        get_scenario("thick2")
    assert SIZES.names() == ("tiny", "quick", "full")
    # Every selection names registered models; an unknown name is refused, naming the list.
    for name in (*selection.VALIDATION_MODELS, *selection.IMAGE_PAIR, *selection.SPEED_MODELS):
        assert name in MODELS
    with pytest.raises(ParameterError, match=r"SIZES: model must be one of .*'exakt'"):
        selection.check_registered(MODELS, ("exact", "exakt"), "SIZES")
