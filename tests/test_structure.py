"""The import structure: no cycles between rotmod's modules, no private imports across packages.

Read with the ast module, so the test sees every module-level import without running code.
Imports inside functions are deliberate late binding (heavy or optional dependencies, the
CLI's fast start) and are not module-level cycles; they are still checked for privacy.
"""

from __future__ import annotations

import ast
from pathlib import Path

import rotmod

SRC = Path(rotmod.__file__).resolve().parent
#: Top-level private helper modules meant to be shared by every package.
SHARED_PRIVATE = {"rotmod._validate", "rotmod._deps"}


def _modules() -> dict[str, Path]:
    out = {}
    for p in SRC.rglob("*.py"):
        rel = p.relative_to(SRC.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _imports(path: Path, module: str, *, top_level_only: bool) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    if top_level_only:  # also imports under `if TYPE_CHECKING:` are not runtime imports
        nodes = [n for n in nodes if not isinstance(n, ast.If)]
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


def test_no_import_cycles_at_module_level() -> None:
    mods = _modules()
    graph = {
        m: {r for name, _ in _imports(p, m, top_level_only=True)
            if (r := _resolve(name, mods)) and r != m}
        for m, p in mods.items()
    }
    # A package's __init__ importing its own submodules is how packages re-export; a cycle
    # is a path from a module back to itself that does not only pass through that.
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for r in sorted(graph[m]):
            if r.startswith(m + ".") or m.startswith(r + "."):
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
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


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
