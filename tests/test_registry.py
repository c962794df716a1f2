"""The one registry type: lookup, 'did you mean', mapping access, redefinition."""

from __future__ import annotations

import functools

import pytest

from rotmod.errors import ParameterError, UnknownNameError
from rotmod.profiles import MODELS
from rotmod.reconstruction import ALGORITHMS
from rotmod.registry import Registry
from rotmod.sky.geometry import GRID_KINDS


def _define(source: str, name: str) -> type:
    """A class defined from source in a module called 'notebook' (as a cell would)."""
    namespace: dict = {"__name__": "notebook"}
    exec(source, namespace)
    return namespace[name]


def test_lookup_lists_names_and_suggests_the_closest() -> None:
    r: Registry[int] = Registry("colour")
    r.register("red", 1)
    r.register("green", 2)
    assert r.get("red") == 1 and r["green"] == 2
    assert r.names() == ("red", "green") == r.keys() and r.values() == (1, 2)
    assert "red" in r and "blue" not in r and len(r) == 2 and list(r) == ["red", "green"]
    with pytest.raises(UnknownNameError, match=r"colour must be one of \['red', 'green'\], "
                                               r"got 'gren'; did you mean 'green'\?"):
        r.get("gren")
    # One error for both ways of asking: a rotmod ParameterError and a mapping's KeyError,
    # whose message reads like every other rotmod message (no extra quotes).
    with pytest.raises(KeyError) as info:
        r["blue"]
    assert isinstance(info.value, ParameterError)
    assert str(info.value).startswith("colour must be one of")
    with pytest.raises(ParameterError, match="--colour must be one of"):
        r.get("blue", parameter="--colour")
    with pytest.raises(ParameterError, match="got 3"):
        r.get(3)


def test_a_definition_run_again_replaces_itself_and_nothing_else() -> None:
    r: Registry[type] = Registry("model")
    first = _define("class Flat:\n    pass\n", "Flat")
    r.register("flat", first)
    again = _define("class Flat:\n    pass\n", "Flat")  # the same cell, run a second time
    r.register("flat", again)
    assert r.get("flat") is again
    other = _define("class Steep:\n    pass\n", "Steep")
    with pytest.raises(ParameterError, match=r"model 'flat' is registered already "
                                             r"\(by notebook\.Flat\)"):
        r.register("flat", other)
    # Bound parameters are part of what is registered (one class under several names).
    r.register("flat-2", functools.partial(again, g1=2))
    r.register("flat-2", functools.partial(again, g1=2))
    with pytest.raises(ParameterError, match="registered already"):
        r.register("flat-2", functools.partial(again, g1=3))
    for bad in ("", None):
        with pytest.raises(ParameterError, match="name must be a non-empty string"):
            r.register(bad, other)


@pytest.mark.parametrize("registry", [MODELS, ALGORITHMS, GRID_KINDS])
def test_rotmods_registries_are_registries(registry: Registry) -> None:
    assert isinstance(registry, Registry) and len(registry) >= 3
    name = registry.names()[0]
    assert registry[name] is registry.get(name)
