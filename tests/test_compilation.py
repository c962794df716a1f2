"""A first run: it says that it compiles and for how long, and compiles in two processes."""

from __future__ import annotations

import sys

import numba
import pytest

from rotmod import compilation
from rotmod.compilation import compile_in_background, warm_kernels
from rotmod.errors import RotmodError
from rotmod.progress import compile_notice


def _fresh(module: str):
    """A numba kernel not yet compiled, as if defined in ``module``."""

    def kernel(x):
        return x + 1.0

    kernel.__module__ = module
    return numba.njit(cache=False)(kernel)


def test_compile_notice_says_when_rotmod_compiles():
    said: list[str] = []
    with compile_notice(said.append):
        assert _fresh("rotmod.somewhere")(1.0) == 2.0
    assert len(said) == 2
    assert said[0].startswith("rotmod: compiling numba kernels")
    assert said[1].startswith("rotmod: compiled 1 numba kernel in")


def test_compile_notice_is_silent_for_others_and_for_compiled_kernels():
    said: list[str] = []
    k = _fresh("rotmod.elsewhere")
    k(1.0)  # compiled before the block: nothing to say inside it
    with compile_notice(said.append):
        _fresh("somebody.else")(1.0)
        k(2.0)
    assert said == []


def test_compile_in_background_starts_at_the_first_compilation_and_stops(monkeypatch):
    started = []

    def popen(cmd, **kw):
        started.append(cmd)
        p = real_popen([sys.executable, "-c", "import time; time.sleep(60)"], **kw)
        started.append(p)
        return p

    real_popen = compilation.subprocess.Popen
    monkeypatch.setattr(compilation.subprocess, "Popen", popen)
    monkeypatch.setattr(compilation, "_cores", lambda: 2)
    with compile_in_background(["exact", compilation.MC_PROFILES]) as bg:
        _fresh("somebody.else")(1.0)
        assert started == [] and not bg.running  # not ours: nothing starts
        _fresh("rotmod.kernel")(1.0)  # ours, compiling: the second process starts
        _fresh("rotmod.other")(1.0)   # once only
        assert len(started) == 2
        cmd, proc = started
        assert cmd[-2:] == ["exact", compilation.MC_PROFILES]  # in the order given
        assert bg.running
    assert proc.poll() is not None    # stopped with the block


def test_background_compilation_finish_waits_and_starts_nothing_after(monkeypatch):
    monkeypatch.setattr(compilation, "_command",
                        lambda names: [sys.executable, "-c", "pass"])
    monkeypatch.setattr(compilation, "_cores", lambda: 2)
    with compile_in_background(["exact"]) as bg:
        _fresh("rotmod.first")(1.0)
        bg.finish()                   # waited for: ended
        assert not bg.running
        monkeypatch.setattr(compilation.subprocess, "Popen",
                            lambda *a, **k: pytest.fail("started after finish"))
        _fresh("rotmod.second")(1.0)


def test_compile_in_background_starts_nothing_on_a_warm_cache(monkeypatch):
    monkeypatch.setattr(compilation.subprocess, "Popen", lambda *a, **k: pytest.fail("start"))
    k = _fresh("rotmod.warm")
    k(1.0)
    with compile_in_background(["exact"]):
        k(2.0)


def test_warm_kernels_refuses_an_unknown_model():
    with pytest.raises(RotmodError, match="nonsense"):
        warm_kernels(["nonsense"])


def test_compile_in_background_that_cannot_start_only_loses_the_help(monkeypatch):
    def popen(*a, **k):
        raise OSError("no executable")

    monkeypatch.setattr(compilation.subprocess, "Popen", popen)
    monkeypatch.setattr(compilation, "_cores", lambda: 2)
    with compile_in_background(["exact"]) as bg:
        assert _fresh("rotmod.failing")(1.0) == 2.0
        assert not bg.running
