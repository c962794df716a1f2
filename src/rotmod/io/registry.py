"""One door to every file: readers and writers registered by (class, format).

In the spirit of astropy's unified I/O, but small: each file format rotmod writes or reads is
registered once, for the class it holds, with the file-name extensions that announce it::

    rotmod.io.write(events, "obs.fits")                 # the EventList writer, FITS
    events = rotmod.io.read("obs.fits")                 # the file says what it holds
    cfg = rotmod.io.read("inst.toml", cls=InstrumentConfig)

A class is named by its import path (``"rotmod.events.EventList"``), so registering a format
never imports the class's package (the registrations live in :mod:`rotmod.io`, below the
science packages).  A writer is called as ``writer(obj, path, overwrite=..., **kw)`` and
applies the one overwrite policy (:func:`rotmod.io.atomic.check_overwrite`) and an atomic
write itself; a reader is ``reader(path, **kw)``.  When several classes share an extension
(``.fits``: event lists, folded profiles, images), each format's ``identify(path)`` says
whether a file is its own.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rotmod.errors import ParameterError
from rotmod.registry import Registry

__all__ = ["FileFormat", "formats", "read", "register", "write"]


@dataclass(frozen=True)
class FileFormat:
    """A file format of one class.

    Parameters
    ----------
    cls : str
        Import path of the class the format holds (``"rotmod.events.EventList"``).
    name : str
        The format's name (``"fits"``, ``"toml"``, ``"ecsv"``).
    reader, writer : callable, optional
        ``reader(path, **kw) -> object``; ``writer(obj, path, *, overwrite=False, **kw)``.
    extensions : tuple of str
        File-name endings (lower case, with the dot) that announce the format.
    identify : callable, optional
        ``identify(path) -> bool``: whether an existing file is this format's (needed only
        when another format shares an extension).
    """

    cls: str
    name: str
    reader: Callable[..., Any] | None = None
    writer: Callable[..., Any] | None = None
    extensions: tuple[str, ...] = ()
    identify: Callable[[Path], bool] | None = None


#: Formats of each class (by import path), each a Registry of formats by name.
_CLASSES: Registry[Registry[FileFormat]] = Registry("class")


def _class_name(cls: type | str) -> str:
    return cls if isinstance(cls, str) else f"{cls.__module__}.{cls.__qualname__}"


def register(
    cls: type | str, name: str, *, reader: Callable[..., Any] | None = None,
    writer: Callable[..., Any] | None = None, extensions: tuple[str, ...] = (),
    identify: Callable[[Path], bool] | None = None,
) -> FileFormat:
    """Register the format ``name`` of ``cls`` (a class or its import path).

    Raises
    ------
    ParameterError
        The format is registered for that class already, or neither reader nor writer is
        given.
    """
    key = _class_name(cls)
    if reader is None and writer is None:
        raise ParameterError(f"format {name!r} of {key}: give a reader, a writer or both")
    if key not in _CLASSES:
        _CLASSES.register(key, Registry(f"format of {key}"))
    fmt = FileFormat(key, name, reader, writer, tuple(e.lower() for e in extensions), identify)
    _CLASSES.get(key).register(name, fmt)
    return fmt


def formats() -> list[FileFormat]:
    """Every registered format, in registration order."""
    return [fmt for _, reg in _CLASSES.items() for _, fmt in reg.items()]


def _listing(role: str) -> str:
    have = [f"{f.cls} ({f.name}: {', '.join(f.extensions) or 'no extension'})"
            for f in formats() if getattr(f, role) is not None]
    return "; ".join(have) or "none"


def _by_extension(candidates: list[FileFormat], path: Path) -> list[FileFormat]:
    name = path.name.lower()
    return [f for f in candidates if any(name.endswith(e) for e in f.extensions)]


def write(obj: Any, path: str | os.PathLike, *, format: str | None = None,
          overwrite: bool = False, **kw: Any) -> Path:
    """Write ``obj`` to ``path`` with the writer registered for its class.

    Parameters
    ----------
    obj : object
        An object of a class with a registered writer (its base classes count).
    path : str or path-like
    format : str, optional
        The format's name; default: guessed from the extension of ``path``.
    overwrite : bool
        Replace an existing file (default: refuse).
    **kw
        Passed to the writer.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    ParameterError
        No writer for the object's class, an unknown format, or an extension that names no
        format of the class (the message lists what is registered).
    """
    p = Path(path)
    classes = [_class_name(c) for c in type(obj).__mro__]
    owner = next((c for c in classes if c in _CLASSES), None)
    writers = [] if owner is None else [f for _, f in _CLASSES.get(owner).items() if f.writer]
    if not writers:
        raise ParameterError(
            f"obj: no writer is registered for {_class_name(type(obj))}; writers: "
            f"{_listing('writer')}"
        )
    if format is not None:
        fmt = _CLASSES.get(owner).get(format, parameter="format")
        if fmt.writer is None:
            raise ParameterError(f"format {format!r} of {owner} is read-only; writers: "
                                 f"{', '.join(f.name for f in writers)}")
    else:
        match = _by_extension(writers, p)
        if not match:
            raise ParameterError(
                f"path {str(p)!r}: the extension names no format {owner} is written in; use "
                + ", ".join(f"{', '.join(f.extensions)} ({f.name})" for f in writers)
                + " or pass format="
            )
        fmt = match[0]
    return fmt.writer(obj, p, overwrite=overwrite, **kw)


def read(path: str | os.PathLike, *, cls: type | str | None = None, format: str | None = None,
         **kw: Any) -> Any:
    """Read ``path`` with the registered reader of ``cls`` (default: the file's own class).

    Parameters
    ----------
    path : str or path-like
    cls : type or str, optional
        The class to read (or its import path).  Default: the one class whose format
        matches the extension (and, when several share it, whose ``identify`` accepts the
        file).
    format : str, optional
        The format's name; default: guessed from the extension.
    **kw
        Passed to the reader.

    Raises
    ------
    ParameterError
        No such file, no reader for ``cls`` or for the file, an unknown format, or a file
        that several classes could hold (pass ``cls``).
    """
    p = Path(path)
    if not p.is_file():
        # Before any guessing: a missing file is what to say, not which reader might fit.
        what = "is not a file" if p.exists() else "does not exist"
        raise ParameterError(f"path {str(p)!r} {what}")
    if cls is not None:
        key = _class_name(cls)
        if key not in _CLASSES:
            raise ParameterError(f"cls: no reader is registered for {key}; readers: "
                                 f"{_listing('reader')}")
        candidates = [f for _, f in _CLASSES.get(key).items() if f.reader]
    else:
        candidates = [f for f in formats() if f.reader]
    if format is not None:
        named = [f for f in candidates if f.name == format]
        if not named:
            raise ParameterError(
                f"format must be one of {sorted({f.name for f in candidates})} for "
                f"{_class_name(cls) if cls is not None else 'any class'}, got {format!r}"
            )
        candidates = named
    else:
        candidates = _by_extension(candidates, p)
    if len(candidates) > 1:
        own = [f for f in candidates if f.identify is not None and f.identify(p)]
        candidates = own or candidates
    if len(candidates) != 1:
        what = "no" if not candidates else "more than one"
        raise ParameterError(
            f"path {str(p)!r}: {what} registered reader matches "
            f"{'it' if cls is None else _class_name(cls)}"
            + (f" ({', '.join(f'{f.cls} ({f.name})' for f in candidates)}); pass cls= or "
               "format=" if candidates else f"; readers: {_listing('reader')}")
        )
    return candidates[0].reader(p, **kw)
