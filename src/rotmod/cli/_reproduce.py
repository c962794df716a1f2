"""``rotmod reproduce``: regenerate the seed paper's results into a folder with a report."""

from __future__ import annotations

import argparse
from typing import Any

from rotmod.cli._common import UserError, add_progress, count, progress_wanted, say
from rotmod.paper.report import STEPS, reproduce
from rotmod.profiles import DEFAULT_COMPARISON


def register(sub: Any) -> None:
    p = sub.add_parser(
        "reproduce",
        help="regenerate the seed paper's results with an HTML report",
        description="Regenerate the seed paper's results (profile figures: Monte Carlo vs "
        f"{' vs '.join(DEFAULT_COMPARISON)}; the speed table; the three image figures; the "
        "two-source lab-prototype result) into DIR with DIR/index.html saying, per result, "
        "what the paper claimed and what rotmod obtained, and DIR/summary.png. Each step "
        "writes its outputs atomically; a rerun skips finished steps (--force redoes them).",
        epilog="example: rotmod reproduce --quick --output rotmod-output",
    )
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true",
                      help="reduced run (fewer photons, smaller grids; a few minutes)")
    size.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--force", action="store_true", help="redo steps whose outputs exist")
    p.add_argument("--steps", default=None, metavar="LIST",
                   help=f"comma-separated subset of steps ({', '.join(STEPS)}); the report "
                   "is always written")
    p.add_argument("--seed", type=count(0), default=1, help="base seed (default 1)")
    add_progress(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    size = "tiny" if args.tiny else "quick" if args.quick else "full"
    steps = None
    if args.steps:
        steps = [s.strip() for s in args.steps.split(",") if s.strip()]
        bad = [s for s in steps if s not in STEPS]
        if bad:
            raise UserError(f"--steps: unknown step(s) {', '.join(bad)}; steps are "
                            f"{', '.join(STEPS)}")
    result = reproduce(args.output, size=size, force=args.force, steps=steps, seed=args.seed,
                       log=say, progress=progress_wanted(args))
    say(f"rotmod: report {result.index} ({result.run_time:.0f} s); summary figure "
        f"{result.summary}")
    return 0
