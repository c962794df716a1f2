"""``rotmod reproduce`` at a tiny size: index.html with every section, summary.png, reruns."""

from __future__ import annotations

import json

import pytest

from rotmod.cli import main
from rotmod.errors import ParameterError
from rotmod.report import reproduce


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro")
    assert main(["reproduce", "--tiny", "--output", str(out)]) == 0
    return out


def test_tiny_reproduce_writes_report(tiny) -> None:
    index = (tiny / "index.html").read_text()
    for section in ("id='profiles'", "id='speed'", "id='images'", "id='prototype'",
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
    import rotmod.report as rep

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
