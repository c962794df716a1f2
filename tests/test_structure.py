"""The import structure: no cycles between rotmod's modules, no private imports across packages.

Read with the ast module, so the test sees every import without running code.  rotmod's own
modules are imported at module level, so that the imports show the real layering; the only
function-local imports of rotmod modules are the few lazy delegations of a lower layer to the
file layer (:data:`LAZY_DELEGATIONS`), and even counting every function-local import there is
no cycle besides them.  Function-local imports of other packages (optional or heavy ones:
matplotlib, zarr, distributed, ...) are late binding and not checked here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import rotmod

SRC = Path(rotmod.__file__).resolve().parent
#: Top-level private helper modules meant to be shared by every package.
SHARED_PRIVATE = {"rotmod._validate", "rotmod._deps",
                  # One random number generator for every numba kernel (Monte Carlo of the
                  # instrument and of the detectors' energy response).
                  "rotmod._rng"}
#: The only imports of rotmod modules inside functions: a lower-layer class that offers
#: ``.read``/``.write`` delegating to the file layer (rotmod.io), which builds on it (at module
#: level each would be a cycle; inside the method it runs after both modules are loaded), and
#: the package's own names, loaded on first use.
LAZY_DELEGATIONS = {
    ("rotmod.config", "rotmod.io.config"):
        "InstrumentConfig.read/.write/.to_toml, `extends` and the moved file functions "
        "(rotmod.config.load_instrument, ...) are rotmod.io.config's, which reads and writes "
        "InstrumentConfig",
    ("rotmod.sky.attitude", "rotmod.io.tables"):
        "AttitudeTable.read/.write are rotmod.io.tables', which reads and writes AttitudeTable",
    # Not a delegation to io: the package's re-exported names load on first use (PEP 562),
    # so that `rotmod --help` starts without numba and astropy.
    ("rotmod", "rotmod.geometry"): "rotmod.Instrument, .Mask, .DetectorArray on first use",
    ("rotmod", "rotmod.materials"): "rotmod.Material on first use",
    ("rotmod", "rotmod.profiles"): "rotmod.get_model on first use",
}
#: The layers, lowest first (docs/architecture.md): a module imports, at module level, from
#: its own layer or lower ones only.  A unit is a top-level module or package of rotmod
#: (``"rotmod"`` is the package's own ``__init__``, which re-exports the instrument and the
#: profile models).  Within a layer, the cycle tests keep the arrows one way.
LAYERS: list[tuple[str, set[str]]] = [
    ("rules", {"errors", "conventions", "_validate", "_deps", "_rng", "limits", "registry",
               "binning",
               "progress",
               "energy"}),
    ("instrument", {"materials", "geometry", "config"}),
    ("models", {"profiles", "rotmod"}),
    ("sky and data", {"sky", "events"}),
    ("simulation", {"montecarlo", "spectral"}),
    ("files", {"io"}),
    ("response", {"response"}),
    ("users", {"reconstruction", "sources", "bursts", "calibration", "design", "plotting",
               "testing", "compilation"}),
    ("products", {"paper", "cli"}),
]
#: ``hasattr`` calls allowed in src (module path relative to src/rotmod -> why): none.  Ask
#: the type (isinstance, or a declared attribute that may be None) instead of probing.
HASATTR_ALLOWED: dict[str, str] = {}


def _modules() -> dict[str, Path]:
    out = {}
    for p in SRC.rglob("*.py"):
        rel = p.relative_to(SRC.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _local_nodes(tree: ast.Module) -> set[int]:
    """``id`` of every import statement inside a function."""
    return {id(n) for f in ast.walk(tree) if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)
            for n in ast.walk(f) if isinstance(n, ast.Import | ast.ImportFrom)}


def _imports(path: Path, module: str, *, top_level_only: bool = False,
             local_only: bool = False) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    if top_level_only:  # also imports under `if TYPE_CHECKING:` are not runtime imports
        nodes = [n for n in nodes if not isinstance(n, ast.If)]
    elif local_only:
        local = _local_nodes(tree)
        nodes = [n for n in nodes if id(n) in local]
    else:  # every runtime import: not those under `if TYPE_CHECKING:`
        typing_only = {id(n) for b in tree.body if isinstance(b, ast.If)
                       and "TYPE_CHECKING" in ast.unparse(b.test) for n in ast.walk(b)}
        nodes = [n for n in nodes if id(n) not in typing_only]
    found = []
    pkg = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    for n in nodes:
        if isinstance(n, ast.Import):
            found += [(a.name, n.lineno) for a in n.names if a.name.startswith("rotmod")]
        elif isinstance(n, ast.ImportFrom):
            base = n.module or ""
            if n.level:
                base = ".".join([*pkg.split(".")[:len(pkg.split(".")) - n.level + 1], base])
            if base.startswith("rotmod"):
                found += [(f"{base}.{a.name}", n.lineno) for a in n.names]
    return found


def _resolve(name: str, mods: dict[str, Path]) -> str | None:
    while name and name not in mods:
        name = name.rsplit(".", 1)[0] if "." in name else ""
    return name or None


def _cycles(graph: dict[str, set[str]], *, skip_family: bool = True) -> list[list[str]]:
    # A package's __init__ importing its own submodules is how packages re-export; a cycle
    # is a path from a module back to itself that does not only pass through that
    # (``skip_family``; without it the graph must leave those edges out itself).
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for r in sorted(graph[m]):
            if skip_family and (r.startswith(m + ".") or m.startswith(r + ".")):
                continue  # parent package <-> its own submodule
            if state.get(r) == 1:
                cycles.append([*stack[stack.index(r):], r])
            elif r not in state:
                visit(r)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    return cycles


def test_no_import_cycles_at_module_level() -> None:
    mods = _modules()
    graph = {
        m: {r for name, _ in _imports(p, m, top_level_only=True)
            if (r := _resolve(name, mods)) and r != m}
        for m, p in mods.items()
    }
    cycles = _cycles(graph)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def _with_packages(module: str, target: str, mods: dict[str, Path]) -> set[str]:
    """``target`` and the packages above it that importing it runs (``rotmod.io.tables``
    runs ``rotmod.io``'s ``__init__`` first).  The packages ``module`` is inside are being
    imported already (Python hands out the partly run package), so they count only when
    they are the ``target`` itself: ``from rotmod.sky import X`` in ``rotmod.sky.grid`` needs
    ``rotmod.sky``'s ``__init__`` to have run that far."""
    parts = target.split(".")
    out = {".".join(parts[:k]) for k in range(2, len(parts))}
    out = {r for r in out if not module.startswith(r + ".")} | {target}
    return {r for r in out if r in mods and r != module}


def test_no_import_cycles_with_local_imports() -> None:
    """Every import, function-local ones included (and the package ``__init__`` each import
    runs), makes no cycle: the layering runs one way.  The lazy delegations to the file layer
    (:data:`LAZY_DELEGATIONS`) are left out; each must still exist and be function-local."""
    mods = _modules()
    graph: dict[str, set[str]] = {}
    used = set()
    for m, p in mods.items():
        graph[m] = set()
        for name, _ in _imports(p, m):
            r = _resolve(name, mods)
            if not r or r == m:
                continue
            if (m, r) in LAZY_DELEGATIONS:
                used.add((m, r))
                continue
            graph[m] |= _with_packages(m, r, mods)
    assert used == set(LAZY_DELEGATIONS), (
        f"lazy delegations listed but gone: {sorted(set(LAZY_DELEGATIONS) - used)}")
    cycles = _cycles(graph, skip_family=False)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_rotmod_imports_at_module_level() -> None:
    """rotmod's own modules are imported at module level (so the imports show the layering),
    except the lazy delegations to the file layer."""
    mods = _modules()
    bad = []
    for m, p in mods.items():
        for name, line in _imports(p, m, local_only=True):
            r = _resolve(name, mods)
            if r and (m, r) not in LAZY_DELEGATIONS:
                bad.append(f"{p.relative_to(SRC.parent)}:{line} imports {name} in a function")
    assert not bad, "function-local imports of rotmod modules:\n" + "\n".join(bad)


def _unit(module: str) -> str:
    parts = module.split(".")
    return "rotmod" if len(parts) == 1 else parts[1]


def test_imports_run_downhill_through_the_layers() -> None:
    layer = {unit: i for i, (_, units) in enumerate(LAYERS) for unit in units}
    mods = _modules()
    missing = sorted({_unit(m) for m in mods} - set(layer))
    assert not missing, f"modules in no layer (add them to LAYERS): {missing}"
    upward = []
    for m, p in mods.items():
        for name, line in _imports(p, m, top_level_only=True):
            r = _resolve(name, mods)
            if r and layer[_unit(r)] > layer[_unit(m)]:
                upward.append(f"{p.relative_to(SRC.parent)}:{line} ({LAYERS[layer[_unit(m)]][0]})"
                              f" imports {r} ({LAYERS[layer[_unit(r)]][0]})")
    assert not upward, "imports running up the layers:\n" + "\n".join(upward)


def test_no_hasattr() -> None:
    """No probing with ``hasattr`` (of operators, grids or anything else): the types say what
    an object has.  Allowed only in :data:`HASATTR_ALLOWED`, with the reason."""
    bad = []
    for p in sorted(SRC.rglob("*.py")):
        rel = p.relative_to(SRC).as_posix()
        for n in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if (isinstance(n, ast.Call) and isinstance(n.func, ast.Name)
                    and n.func.id == "hasattr" and rel not in HASATTR_ALLOWED):
                bad.append(f"{rel}:{n.lineno}: {ast.unparse(n)}")
    assert not bad, "hasattr calls:\n" + "\n".join(bad)


def test_no_private_imports_across_packages() -> None:
    mods = _modules()
    bad = []
    for m, p in mods.items():
        home = m.split(".")[1] if "." in m else ""
        for name, line in _imports(p, m, top_level_only=False):
            parts = name.split(".")
            private = [i for i, s in enumerate(parts) if s.startswith("_") and not s.endswith("__")]
            if not private:
                continue
            owner = ".".join(parts[: private[0] + 1])
            if owner in SHARED_PRIVATE or owner.split(".")[1] == home:
                continue
            bad.append(f"{p.relative_to(SRC.parent)}:{line} imports {name}")
    assert not bad, "private names used across packages:\n" + "\n".join(bad)
