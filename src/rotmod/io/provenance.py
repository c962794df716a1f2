"""Where a file came from: the provenance cards every FITS product of rotmod carries.

:func:`provenance_cards` is the one place the cards are built; the writers of event lists,
folded profiles and images (:mod:`rotmod.io.events`, :mod:`rotmod.io.images`) add them to
their headers:

* ``CREATOR``: ``rotmod <version>`` (``rotmod.__version__``, from setuptools-scm at install);
* ``RMCOMMIT``: the git commit of the code that ran (with ``+dirty`` for uncommitted
  changes), when it runs from a git checkout (:func:`git_commit`, which the paper's
  provenance record uses too);
* ``DATE``: when the file was written (UTC, ISO 8601, as FITS defines it);
* ``TELESCOP``/``INSTRUME``: the caller's names (default ``rotmod``);
* ``SEED``: the random seed as an integer (a :class:`numpy.random.SeedSequence`'s entropy),
  when the caller gives one;
* ``COMMAND``: the command line or parameters that made the file, when the caller gives them
  (long values continue on ``CONTINUE`` cards);
* ``LONGSTRN``: announces the ``CONTINUE`` convention (OGIP 1.0) for any long text card.
"""

from __future__ import annotations

import datetime
import functools
import os
import shlex
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import rotmod
from rotmod.errors import ParameterError
from rotmod.io._fits import header_text

__all__ = ["creator", "fitting_comment", "git_commit", "provenance_cards", "seed_value"]

#: The OGIP long-string convention: CONTINUE cards may follow a string value.
LONGSTRN = ("LONGSTRN", "OGIP 1.0", "long string values continue on CONTINUE cards")


def git_commit(start: str | os.PathLike | None = None) -> str | None:
    """The commit (and ``+dirty`` when the work tree has changes) of the checkout holding
    ``start`` (default: this package), or None when it is not a git checkout."""
    if start is None:
        return _package_commit()
    return _commit_of(Path(start))


@functools.cache
def _package_commit() -> str | None:
    # Asked once per process: every file written in a run names the same code.
    return _commit_of(Path(__file__).resolve().parent)


def _commit_of(where: Path) -> str | None:
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True,
            timeout=10, check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=where,
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{sha}+dirty" if dirty else sha or None


def creator() -> str:
    """``rotmod <version>``: the software that writes a file."""
    return f"rotmod {rotmod.__version__}"


def seed_value(seed: Any) -> int | str | None:
    """The seed as one header value: an int (a SeedSequence's entropy; a Generator's, when
    it was seeded from one), or the decimal digits when it exceeds a FITS integer.

    Raises
    ------
    ParameterError
        ``seed`` is none of None, int, SeedSequence or Generator.
    """
    if seed is None:
        return None
    if isinstance(seed, np.random.Generator):
        seed = seed.bit_generator.seed_seq
    if isinstance(seed, np.random.SeedSequence):
        seed = seed.entropy
    if isinstance(seed, bool | str) or not isinstance(seed, int | np.integer | Sequence):
        raise ParameterError(
            f"seed must be an int, a SeedSequence or a Generator, got {type(seed).__name__}")
    if isinstance(seed, Sequence):  # a SeedSequence built from a list of ints
        return " ".join(str(int(s)) for s in seed)
    seed = int(seed)
    # A default SeedSequence's entropy is 128 bits: FITS integers hold 64.
    return seed if -(2**63) <= seed < 2**63 else str(seed)


def provenance_cards(*, telescop: str = "rotmod", instrume: str = "rotmod", seed: Any = None,
                     command: str | Sequence[str] | None = None) -> list[tuple[str, Any, str]]:
    """The provenance cards ``(keyword, value, comment)`` of a FITS product (module notes).

    Parameters
    ----------
    telescop, instrume : str
        Mission and instrument names (default ``rotmod``).
    seed : int, SeedSequence or Generator, optional
        The randomness of the run that made the file.
    command : str or sequence of str, optional
        The command line (``sys.argv``) or parameters that made the file.
    """
    cards: list[tuple[str, Any, str]] = [
        ("CREATOR", creator(), "software"),
    ]
    commit = git_commit()
    if commit is not None:
        cards.append(("RMCOMMIT", commit, "rotmod git commit"))
    now = datetime.datetime.now(datetime.UTC).replace(tzinfo=None)
    cards += [
        ("DATE", now.isoformat(timespec="seconds"), "file creation date (UTC)"),
        ("TELESCOP", header_text(str(telescop)), "mission or telescope"),
        ("INSTRUME", header_text(str(instrume)), "instrument"),
    ]
    value = seed_value(seed)
    if value is not None:
        cards.append(("SEED", value, "random seed (SeedSequence entropy)"))
    if command is not None:
        text = command if isinstance(command, str) else shlex.join(str(c) for c in command)
        cards.append(("COMMAND", header_text(text), "command that made this file"))
    # Always announced: any text card of a product (a command, a path, parameters) may be
    # long enough to continue on CONTINUE cards.
    return [(k, v, fitting_comment(k, v, c)) for k, v, c in [*cards, LONGSTRN]]


def fitting_comment(key: str, value: Any, comment: str) -> str:
    """``comment``, or none when a one-card value (a long version string) leaves it no room:
    astropy would cut it with a warning."""
    if not isinstance(value, str) or len(value) > 68:  # numbers fit; long text: CONTINUE
        return comment
    # "KEY     = " and the quoted value, which astropy pads to 20 characters.
    width = 10 + max(len(value.replace("'", "''")) + 2, 20)
    return comment if width + 3 + len(comment) <= 80 else ""
