"""Helpers shared by the subcommands: instrument, sources, energies, outputs, progress."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import astropy.units as u
import numpy as np

from rotmod.binning import EnergyBand
from rotmod.errors import RotmodError
from rotmod.io import figures as io_figures
from rotmod.io import tables as io_tables
from rotmod.io.atomic import check_overwrite
from rotmod.io.config import list_presets, load_instrument_config, preset_path
from rotmod.io.response_store import as_store_path, check_partial, store_paths
from rotmod.progress import Progress
from rotmod.registry import Registry
from rotmod.sky import Attitude, AttitudeTable, SkyGeometry

if TYPE_CHECKING:
    from rotmod.config import InstrumentConfig
    from rotmod.geometry import Instrument

log = logging.getLogger("rotmod.cli")

#: Mask-angle bins per rotation shared by ``fold`` and ``response``, so that their defaults
#: chain: one bin per degree of mask rotation (the seed paper used 560; pass ``--bins 560`` to
#: both to reproduce it).  A response's cost grows with the bins, and 1 deg bins already
#: sample the modulation of the presets' masks several times per period.
DEFAULT_BINS = 360
BINS_HELP = (f"mask-angle bins per rotation (default {DEFAULT_BINS}: one per degree, the same "
             "in rotmod fold and rotmod response so that their files chain; the seed paper "
             "used 560)")


class UserError(RotmodError):
    """A mistake on the command line that argparse cannot see (bad file, bad combination)."""


def add_instrument(p: argparse.ArgumentParser, *, default: str | None = "paper") -> None:
    """``--instrument FILE|PRESET`` (and ``--energy``)."""
    p.add_argument(
        "-i", "--instrument", default=default, metavar="FILE|PRESET",
        help="instrument description (TOML/YAML file) or preset name "
        f"({', '.join(list_presets())}){'; default ' + default if default else ''}; "
        "a preset whose detectors all sit on the rotation axis (paper) cannot tell a "
        "source from its 180 deg mirror (see 'rotmod --help')",
    )


def mirror_degenerate(instrument: Instrument) -> bool:
    """Whether every detector of ``instrument`` is on the rotation axis (see
    :data:`MIRROR_NOTE`): then a source and its 180 deg mirror give the same profiles."""
    pos = np.asarray(instrument.detectors.positions, dtype=float)  # cm
    return bool(np.all(np.hypot(pos[:, 0], pos[:, 1]) <= 1e-9))


def warn_if_mirror_degenerate(instrument: Instrument, what: str) -> bool:
    """Log a warning (a line on stderr in the CLI) when ``instrument`` cannot tell a source
    from its mirror; return whether it warned."""
    if not mirror_degenerate(instrument):
        return False
    log.warning("%s: all %d detector(s) of this instrument are on the rotation axis, so a "
                "source at (theta, phi) and its mirror at (theta, phi + 180 deg) give the "
                "same profiles; an image shows both (use an array such as the 'prototype' "
                "preset to tell them apart)", what, len(instrument.detectors))
    return True


def describe_position(grid: SkyGeometry, index: int) -> str:
    """Pixel ``index`` of ``grid`` in degrees: RA/Dec on a celestial grid, else the
    instrument-frame zenith and azimuth."""
    if grid.frame == "celestial":
        c = grid.sky_coords().ravel()[index]
        return f"RA {c.ra.deg:.3f} deg, Dec {c.dec.deg:+.3f} deg"
    theta, phi = grid.directions()
    th = float(np.ravel(theta.to_value(u.deg))[index])
    ph = float(np.ravel(phi.to_value(u.deg))[index]) % 360.0
    return f"theta {th:.3f} deg, phi {ph:.3f} deg (instrument frame)"


def parse_radec(text: str, option: str) -> tuple[float, float]:
    """``RA,DEC`` in degrees (each may carry a unit), with ``-90 <= DEC <= 90``."""
    parts = [x.strip() for x in text.split(",")]
    if len(parts) != 2:
        raise UserError(f"{option}: must be RA,DEC in degrees, got {text!r}")
    try:
        ra, dec = (to_number(x, "deg") for x in parts)
    except argparse.ArgumentTypeError as exc:
        raise UserError(f"{option}: RA,DEC: {exc}") from None
    if not -90.0 <= dec <= 90.0:
        raise UserError(f"{option}: Dec must be in [-90, 90] deg, got {dec:g} in {text!r}")
    return ra, dec


def add_attitude(p: argparse.ArgumentParser) -> None:
    """``--attitude FILE`` or ``--pointing RA,DEC [--roll DEG]``: where the instrument points."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--attitude", default=None, metavar="FILE",
                   help="attitude table (ECSV or FITS: columns time [s], ra, dec, roll [deg]) "
                   "of a drifting observation")
    g.add_argument("--pointing", default=None, metavar="RA,DEC",
                   help="fixed pointing of the rotation axis (ICRS, deg)")
    p.add_argument("--roll", type=quantity("deg"), default=None, metavar="DEG",
                   help="with --pointing: position angle (east of north) of the instrument's "
                   "+y axis (deg; default 0)")
    p.add_argument("--max-step", type=quantity("s"), default=60.0, metavar="SECONDS",
                   help="with --attitude: longest piece of constant attitude (s; default 60)")


def attitude_of(args: argparse.Namespace) -> Attitude | AttitudeTable | None:
    """The ``--attitude`` table or the fixed ``--pointing``/``--roll`` (``None``: neither)."""
    if args.roll is not None and args.pointing is None:
        raise UserError(f"--roll: goes with --pointing (an --attitude table has its own roll), "
                        f"got --roll {args.roll:g} without it")
    if args.attitude is not None:
        return AttitudeTable.read(check_input(args.attitude, "--attitude"))
    if args.pointing is not None:
        return Attitude(*parse_radec(args.pointing, "--pointing"), args.roll or 0.0)
    return None


def intervals_of(table: AttitudeTable, t_start: float, t_stop: float,
                 max_step: float) -> list[tuple[float, float, Attitude]]:
    """The pieces of constant attitude of ``table`` over ``[t_start, t_stop]`` (s)."""
    if not np.isfinite(max_step) or max_step <= 0:
        raise UserError(f"--max-step: must be > 0 s, got {max_step:g} s")
    check_covers(table, t_start, t_stop, "give an --exposure within the table")
    return table.intervals(t_start, t_stop, max_step)


def check_covers(table: AttitudeTable, t_start: float, t_stop: float, hint: str) -> None:
    """Refuse an ``--attitude`` table that does not cover ``[t_start, t_stop]`` (s), by the
    table's own test (:meth:`~rotmod.sky.AttitudeTable.covers`, which its ``at`` and
    ``intervals`` apply too), with the command line's words for it."""
    if not table.covers(t_start, t_stop):
        t0, t1 = table.span
        raise UserError(
            f"--attitude: the table covers {t0:g} .. {t1:g} s, but the observation runs "
            f"{t_start:g} .. {t_stop:g} s; {hint} (times are seconds from the start of the "
            "observation)"
        )


def to_number(text: str, unit: str) -> float:
    """A command-line number: plain (in ``unit``) or with a unit, e.g. ``3deg``, ``5min``.

    Raises
    ------
    argparse.ArgumentTypeError
        Not a number, a unit of the wrong kind, or not finite.
    """
    s = text.strip()
    try:
        value = float(s)
    except ValueError:
        try:
            q = u.Quantity(s)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(
                f"must be a number (in {unit}) or a number with a unit like '3 {unit}', "
                f"got {text!r}"
            ) from None
        try:
            value = float(q.to_value(u.Unit(unit)))
        except u.UnitConversionError:
            raise argparse.ArgumentTypeError(
                f"must be in units of {unit}, got {text!r} ({q.unit})"
            ) from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def quantity(unit: str) -> Callable[[str], float]:
    """argparse ``type=`` for a number in ``unit`` that may also be written with a unit."""

    def conv(text: str) -> float:
        return to_number(text, unit)

    conv.__name__ = f"number in {unit}"
    return conv


def add_energy(p: argparse.ArgumentParser) -> None:
    p.add_argument("-e", "--energy", type=quantity("keV"), default=None, metavar="KEV",
                   help="photon energy (keV, or with a unit: 1.2MeV); "
                   "default the instrument file's first energy")


def add_band(p: argparse.ArgumentParser) -> None:
    """``--band LO:HI``: the events' energy band (:func:`band_of`)."""
    p.add_argument("--band", default=None, metavar="LO:HI",
                   help="keep events with LO <= energy <= HI (keV; each may carry a unit: "
                   "100:0.14MeV)")


def band_of(text: str | None) -> EnergyBand | None:
    """The ``--band LO:HI`` (keV; each may carry a unit), or None."""
    if text is None:
        return None
    lo, sep, hi = text.partition(":")  # each a plain number (keV) or with a unit
    try:
        band = EnergyBand(to_number(lo, "keV"), to_number(hi, "keV")) if sep else None
    except argparse.ArgumentTypeError as exc:
        raise UserError(f"--band: must be LO:HI (keV), got {text!r}: {exc}") from None
    if band is None:
        raise UserError(f"--band: must be LO:HI (keV), got {text!r}")
    return band


def add_progress(p: argparse.ArgumentParser) -> None:
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="report progress: a bar when stderr is a terminal, else a log line "
                   "every few seconds (default on; --no-progress or --quiet for none)")


def add_output(p: argparse.ArgumentParser, *, required: bool = True, help: str = "output file",
               default: str | None = None) -> None:
    p.add_argument("-o", "--output", required=required and default is None, default=default,
                   metavar="PATH", help=help)
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")


def load_config(args: argparse.Namespace) -> InstrumentConfig:
    return load_instrument_config(args.instrument)


def energy_of(args: argparse.Namespace, cfg: Any) -> float:
    if args.energy is not None:
        if not np.isfinite(args.energy) or args.energy <= 0:
            raise UserError(f"--energy: must be > 0 keV, got {args.energy:g} keV")
        return float(args.energy)
    return float(cfg.energies_kev[0])


def iteration_bar(enabled: bool, desc: str) -> Any:
    """A :class:`~rotmod.response.parallel.Progress` of iterations of unknown total (a
    null context when disabled).  A command line draws bars only on a terminal: run from
    a notebook or a script, it logs lines like any batch job."""
    if not enabled:
        return contextlib.nullcontext(None)
    return Progress(None, desc, "it", tty=sys.stderr.isatty())


def heartbeat(args: argparse.Namespace, desc: str, total: int | None = None,
              unit: str = "it") -> Any:
    """Progress of a step that reports little or nothing (a drift response, a Radon table,
    the first call that compiles numba kernels): log lines every few seconds, on a terminal
    too, since a bar would stand still (a null context with ``--no-progress``/``--quiet``)."""
    if not progress_wanted(args):
        return contextlib.nullcontext(None)
    return Progress(total, desc, unit, tty=False)


def progress_wanted(args: argparse.Namespace) -> bool:
    """``--progress``/``--no-progress``; by default on (a bar on a terminal, log lines
    elsewhere) unless ``--quiet``."""
    flag = getattr(args, "progress", None)
    if flag is None:
        return not getattr(args, "quiet", False)
    return bool(flag)


def parse_source(text: str, *, with_rate: bool = False) -> tuple[float, ...]:
    """``THETA,PHI`` (deg) or ``THETA,PHI,RATE`` (deg, deg, 1/s) from the command line."""
    parts = [x.strip() for x in text.split(",")]
    want = "THETA,PHI,RATE" if with_rate else "THETA,PHI"
    if len(parts) not in ((2, 3) if with_rate else (2,)):
        raise argparse.ArgumentTypeError(
            f"must be {want} (degrees{', photons/s' if with_rate else ''}), got {text!r}"
        )
    try:
        units = ("deg", "deg", "1/s")[: len(parts)]
        vals = tuple(to_number(x, un) for x, un in zip(parts, units, strict=True))
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{want}: {exc}, in {text!r}") from None
    if not 0 <= vals[0] < 90:
        raise argparse.ArgumentTypeError(f"zenith must be in [0, 90) deg, got {vals[0]:g}")
    if with_rate and len(vals) == 3 and vals[2] < 0:
        raise argparse.ArgumentTypeError(f"rate must be >= 0 photons/s, got {vals[2]:g}")
    return vals


def source_arg(with_rate: bool = False) -> Callable[[str], tuple[float, ...]]:
    def conv(text: str) -> tuple[float, ...]:
        return parse_source(text, with_rate=with_rate)

    conv.__name__ = "source"
    return conv


def parse_range(text: str) -> np.ndarray:
    """``START:STOP:NUM`` (inclusive, NUM values) or a comma list ``1,2,4`` (not empty:
    argparse names the option, ``argument --a: ...``)."""
    if not text.replace(",", "").strip():
        raise argparse.ArgumentTypeError(
            f"an empty list; must be START:STOP:NUM or a comma-separated list of numbers, "
            f"got {text!r}")
    try:
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise ValueError
            lo, hi, n = float(parts[0]), float(parts[1]), int(parts[2])
            if n < 1:
                raise ValueError
            return np.linspace(lo, hi, n)
        return np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be START:STOP:NUM or a comma-separated list, got {text!r}"
        ) from None


def check_output(path: str | os.PathLike, overwrite: bool, *, what: str = "output") -> Path:
    """Refuse to overwrite unless asked, and make sure the folder exists (one output; a
    command checks all its files at once with :func:`check_files`)."""
    p = Path(path)
    check_overwrite(p, overwrite, parameter=what, flag="--overwrite")
    if not p.parent.exists():
        raise UserError(f"{what} {str(p)!r}: folder {str(p.parent)!r} does not exist")
    return p


def check_plot(path: str | os.PathLike, overwrite: bool, *, what: str = "--plot") -> Path:
    """:func:`check_output` for a plot, which must name an image format matplotlib writes."""
    from matplotlib.backend_bases import FigureCanvasBase

    p = check_output(path, overwrite, what=what)
    formats = FigureCanvasBase.get_supported_filetypes()
    if p.suffix[1:].lower() not in formats:
        raise UserError(f"{what} {str(p)!r}: the extension must be an image format "
                        f"({', '.join(sorted(formats))}), got {p.suffix or 'none'!r}")
    return p


def _same(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file (links and ``..`` included)."""
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def _inside(a: Path, b: Path) -> bool:
    """Whether ``a`` is within the folder ``b`` (``b`` replaced or written removes ``a``).

    An existing ``b`` is compared with each of ``a``'s existing folders by device and inode,
    so a case-insensitive file system or a second mount of one folder cannot hide it.
    """
    if not b.exists():
        return b.resolve() in a.resolve().parents
    return any(q.exists() and os.path.samefile(q, b) for q in a.resolve().parents)


def _clash(a: Path, b: Path) -> str | None:
    """How ``a`` and ``b`` overlap, in words (``None``: they do not)."""
    if _same(a, b):
        return "is also"
    if _inside(a, b):
        return "is inside"
    if _inside(b, a):
        return "holds"
    return None


@dataclass(frozen=True)
class Files:
    """A command's files, checked together (:func:`check_files`): ``inputs`` and ``outputs``
    by option (or argument name), each a :class:`~pathlib.Path`."""

    inputs: dict[str, Path]
    outputs: dict[str, Path]
    overwrite: bool
    #: Output -> the fixed names its writer also uses beside it (a store's ``.partial`` form
    #: and ``.lock``).
    reserved: dict[str, tuple[Path, ...]] = field(default_factory=dict)

    def __getitem__(self, name: str) -> Path | None:
        return self.outputs.get(name, self.inputs.get(name))

    def more(self, outputs: dict[str, Any], *, plots: tuple[str, ...] = ()) -> Files:
        """These files plus ``outputs`` known only later (names made from results), checked
        against every input and every output as :func:`check_files` checks."""
        return check_files(self.inputs, {**self.outputs, **outputs}, self.overwrite,
                           plots=plots, reserved=self.reserved, checked=self)


def check_files(inputs: dict[str, Any], outputs: dict[str, Any], overwrite: bool, *,
                stores: tuple[str, ...] = (), plots: tuple[str, ...] = (),
                reserved: dict[str, tuple[Path, ...]] | None = None,
                checked: Files | None = None) -> Files:
    """The one check of a command's files, before any work.

    Every input exists; no output (nor any name its writer uses beside it) is an input, is
    inside an input folder or holds an input, and no two outputs share a path; an existing
    output is replaced only with ``--overwrite``; every output's folder exists; plots name
    an image format.  Temporary names are never checked: the writers make them unique
    (:mod:`rotmod.io.atomic`).

    Parameters
    ----------
    inputs, outputs : dict
        Option or argument name (as the message should say it) -> path, or ``None`` for one
        not given.  An input given as ``-i``/``--instrument`` may name a preset (its file is
        the input).
    overwrite : bool
        ``--overwrite``.
    stores : tuple of str
        Outputs that are response stores (their ``.partial`` form and ``.lock`` are checked
        too).
    plots : tuple of str
        Outputs that are plots (:func:`check_plot`).
    reserved, checked
        For :meth:`Files.more`: what an earlier call knew and checked.

    Returns
    -------
    Files

    Raises
    ------
    UserError, ParameterError
    """
    ins: dict[str, Path] = dict(checked.inputs) if checked else {}
    for name, value in inputs.items():
        if value is None or name in ins:
            continue
        p = Path(value)
        if name in ("-i", "--instrument") and not (p.exists() or p.is_symlink()):
            # A preset: its file is the input (load_instrument_config says what is wrong
            # with a name that is neither).
            with contextlib.suppress(RotmodError):
                ins[name] = preset_path(str(value))
            continue
        ins[name] = check_input(p, name)
    outs = {name: Path(v) for name, v in outputs.items() if v is not None}
    res = dict(reserved or {})
    for name in stores:
        if name in outs:
            res[name] = store_paths(as_store_path(outs[name]))
    names = list(outs.items())
    for k, (name, p) in enumerate(names):
        taken = [(p, "")] + [(q, f" (its writer also uses {str(q)!r})")
                             for q in res.get(name, ())]
        for q, whose in taken:
            for iname, i in ins.items():
                if how := _clash(q, i):
                    raise UserError(
                        f"{name} {str(p)!r}{whose} {how} an input of this command "
                        f"({iname} {str(i)!r}); write the result to another path "
                        "(--overwrite never replaces an input)")
            for oname, o in names[:k]:
                for r in (o, *res.get(oname, ())):
                    if how := _clash(q, r):
                        raise UserError(
                            f"{name} {str(p)!r}{whose} {how} another output of this "
                            f"command ({oname} {str(r)!r}); give each output its own path")
        if checked is None or name not in checked.outputs:
            (check_plot if name in plots else check_output)(p, overwrite, what=name)
    for name in stores:
        if name in outs:
            check_partial(res[name][0])  # whatever else is in the way, said before any work
    return Files(ins, outs, overwrite, res)


def count(lo: int) -> Callable[[str], int]:
    """argparse ``type=`` for an integer >= ``lo`` (``1e3`` is accepted when it is whole)."""

    def conv(text: str) -> int:
        try:
            # Integer digits exactly (a 128-bit seed does not survive a float); 1e3 and 2.0
            # through float, when whole.
            value: float | int = int(text)
        except ValueError:
            try:
                value = float(text)
            except ValueError:
                raise argparse.ArgumentTypeError(
                    f"must be an integer >= {lo}, got {text!r}") from None
            if not value.is_integer():
                raise argparse.ArgumentTypeError(
                    f"must be an integer >= {lo}, got {text!r}") from None
        if value < lo:
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}, got {text!r}")
        return int(value)

    conv.__name__ = f"integer >= {lo}"
    return conv


def registered(registry: Registry[Any], name: str, option: str) -> str:
    """``name``, if ``registry`` holds it.

    Parameters
    ----------
    registry : Registry
        Where the names are registered (e.g. :data:`rotmod.profiles.MODELS`).
    name : str
        The name given on the command line.
    option : str
        The option that gave it (``"--model"``), which opens the message.

    Raises
    ------
    ParameterError
        An unknown name, in the command line's ``OPTION: rule`` form (the message lists the
        registered names and suggests the closest).
    """
    registry.get(name, parameter=f"{option}:")
    return name


def check_input(path: str | os.PathLike, what: str = "input") -> Path:
    """``path``, which must exist (a file, or a folder such as a response store)."""
    p = Path(path)
    if not p.exists():
        raise UserError(f"{what} {str(p)!r} does not exist")
    return p


def write_table(table: Any, path: Path) -> Path:
    """Write an astropy table as ECSV (``.ecsv``) or CSV (anything else), atomically.

    The output was checked (:func:`check_output`) before the work that made the table.
    """
    return io_tables.write_table(table, path, overwrite=True)


def save_figure(fig: Any, path: Path, dpi: int = 120) -> Path:
    """Save and close a matplotlib figure atomically (Agg backend)."""
    import matplotlib.pyplot as plt

    try:
        # The output was checked (check_plot) before the work that made the figure.
        return io_figures.save_figure(fig, path, dpi=dpi, overwrite=True)
    finally:
        plt.close(fig)


def use_agg() -> None:
    """Select the non-interactive backend (files only)."""
    import matplotlib

    matplotlib.use("Agg", force=True)


def tqdm_progress(total: int, desc: str, unit: str = "it") -> tuple[Callable, Callable]:
    """A ``(update(done, total), close())`` pair: a bar on a terminal, log lines elsewhere
    (:class:`~rotmod.response.parallel.Progress`)."""
    bar = Progress(total, desc, unit, tty=sys.stderr.isatty())
    return bar.update_to, bar.close


def say(msg: str) -> None:
    """One line of status on stderr (stdout stays for results)."""
    print(msg, file=sys.stderr, flush=True)
