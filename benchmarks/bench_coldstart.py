"""A newcomer's first run: ``import rotmod`` and the README's first command, cold and warm.

Run ``python benchmarks/bench_coldstart.py [--repeat 3] [--baseline REV]``.

* ``import``: ``python -c "import rotmod"`` in a fresh process (median of ``--repeat``).
* ``cold``: ``rotmod reproduce --quick`` on an empty numba cache (a new ``NUMBA_CACHE_DIR``
  per run): what the README's first command costs on a new machine after ``pip install``.
  The compile time is the command's own count (its ``compiled N numba kernels in S s``
  line; code without it shows nan) beside the cold run's excess over the warm one.
* ``warm``: the same command again on the cache the cold run left.

With ``--baseline REV`` the same runs are made, interleaved, on a checkout of ``REV`` (a
git worktree in a temporary folder, put first on ``PYTHONPATH``): the straightforward way
to say what a change bought, in one run on one machine.  Wall times are medians; the load
average is printed beside them (the machine is shared).  Results go to
``docs/response.md`` ("A first run").
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd: list[str], src: Path, cache: Path, out: Path) -> tuple[float, float, str]:
    """Wall and CPU seconds of ``cmd`` with ``src`` first on the path, and its stderr."""
    env = dict(os.environ, PYTHONPATH=str(src), NUMBA_CACHE_DIR=str(cache))
    before = os.times()
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, cwd=out, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = os.times()
    if p.returncode:
        sys.exit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-2000:]}")
    cpu = (after.children_user - before.children_user
           + after.children_system - before.children_system)
    return wall, cpu, p.stderr


def _compiled(stderr: str) -> float:
    """The compile seconds the command reports (nan: code that does not report them)."""
    m = re.search(r"compiled (\d+) numba kernels in (\d+) s", stderr)
    return float(m.group(2)) if m else float("nan")


def measure(name: str, src: Path, repeat: int, work: Path) -> dict[str, list[float]]:
    """Every timing of one source tree."""
    r: dict[str, list[float]] = {k: [] for k in ("import", "cold", "cold_cpu", "compile",
                                                  "warm", "warm_cpu")}
    py = sys.executable
    for k in range(repeat):
        cache = work / f"cache-{name}-{k}"
        out = work / f"out-{name}-{k}"
        out.mkdir()
        r["import"].append(_run([py, "-c", "import rotmod"], src, cache, out)[0])
        cmd = [py, "-m", "rotmod.cli", "reproduce", "--quick", "--output", "report"]
        wall, cpu, err = _run(cmd, src, cache, out)
        r["cold"].append(wall)
        r["cold_cpu"].append(cpu)
        r["compile"].append(_compiled(err))
        shutil.rmtree(out / "report")
        wall, cpu, _ = _run(cmd, src, cache, out)
        r["warm"].append(wall)
        r["warm_cpu"].append(cpu)
        print(f"  {name} run {k + 1}: import {r['import'][-1]:.2f} s, cold {r['cold'][-1]:.1f} s,"
              f" warm {wall:.1f} s (load {os.getloadavg()[0]:.2f})", flush=True)
    return r


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--baseline", default=None, metavar="REV",
                   help="also time this git revision (a worktree), interleaved")
    args = p.parse_args()
    trees = {"this": ROOT / "src"}
    with tempfile.TemporaryDirectory(prefix="rotmod-coldstart-") as tmp:
        work = Path(tmp)
        if args.baseline:
            wt = work / "baseline"
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(wt),
                            args.baseline], check=True, capture_output=True)
            trees = {args.baseline: wt / "src", **trees}
        try:
            loads = [os.getloadavg()[0]]
            results = {name: measure(name, src, args.repeat, work)
                       for name, src in trees.items()}
            loads.append(os.getloadavg()[0])
        finally:
            if args.baseline:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                                str(work / "baseline")], capture_output=True)
    med = statistics.median
    print(f"\n`rotmod reproduce --quick`, medians of {args.repeat}; {os.cpu_count()} cores, "
          f"load average {loads[0]:.2f} before, {loads[1]:.2f} after\n")
    print("| code | import rotmod | cold (empty numba cache) | cold - warm | compiling "
          "(reported) | cold CPU | warm | warm CPU | cold / warm |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        print(f"| {name} | {med(r['import']):.2f} s | {med(r['cold']):.1f} s | "
              f"{med(r['cold']) - med(r['warm']):.1f} s | {med(r['compile']):.0f} s | "
              f"{med(r['cold_cpu']):.1f} s | {med(r['warm']):.1f} s"
              f" | {med(r['warm_cpu']):.1f} s | {med(r['cold']) / med(r['warm']):.2f} |")


if __name__ == "__main__":
    main()
