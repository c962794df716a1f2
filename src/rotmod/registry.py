"""One registry type for everything chosen by name.

Profile models, reconstruction algorithms, sky-grid kinds, response store kinds and the
paper's scenarios are each a :class:`Registry`: entries are registered where they are
defined (a decorator or a call), looked up by name with an error that lists the names and
suggests the closest one, and listed by :meth:`Registry.names` wherever a help string or a
list of choices is needed, so that a name is written in exactly one place.

Examples
--------
>>> from rotmod.registry import Registry
>>> shapes = Registry("shape")
>>> @shapes.register("disc")
... class Disc: ...
>>> shapes.get("disc") is Disc
True
>>> shapes.get("dsic")
Traceback (most recent call last):
...
rotmod.errors.ParameterError: shape must be one of ['disc'], got 'dsic'; did you mean 'disc'?
"""

from __future__ import annotations

import difflib
import functools
from collections.abc import Callable, Iterator
from typing import Any, Generic, TypeVar, overload

from rotmod.errors import ParameterError, UnknownNameError

__all__ = ["Registry"]

T = TypeVar("T")


class Registry(Generic[T]):
    """Named entries of one kind, in registration order.

    Parameters
    ----------
    kind : str
        What the entries are, as a parameter name (``"model"``, ``"method"``, ``"grid kind"``):
        it opens the error message of :meth:`get`.
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._entries: dict[str, T] = {}

    @overload
    def register(self, name: str) -> Callable[[T], T]: ...

    @overload
    def register(self, name: str, obj: T) -> T: ...

    def register(self, name: str, obj: Any = None) -> Any:
        """Register ``obj`` under ``name``; without ``obj``, a decorator that does.

        Raises
        ------
        ParameterError
            ``name`` is not a non-empty string, or is registered already by something else
            (a second definition would silently replace the first).  The same class or
            function defined again -- a notebook cell run twice, a reloaded module --
            replaces its earlier self.
        """
        if not isinstance(name, str) or not name:
            raise ParameterError(f"{self.kind} name must be a non-empty string, got {name!r}")

        def add(entry: T) -> T:
            old = self._entries.get(name)
            if old is not None and old is not entry and not _redefinition(old, entry):
                raise ParameterError(f"{self.kind} {name!r} is registered already "
                                     f"(by {_where(old)})")
            self._entries[name] = entry
            return entry

        return add if obj is None else add(obj)

    def get(self, name: Any, *, parameter: str | None = None) -> T:
        """The entry registered as ``name``.

        Parameters
        ----------
        name : str
        parameter : str, optional
            The caller's parameter name for the message (default :attr:`kind`).

        Raises
        ------
        UnknownNameError
            Unknown name (a :class:`ParameterError` and a :class:`KeyError`): the message
            lists the names and suggests the closest one.
        """
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            pass
        msg = f"{parameter or self.kind} must be one of {list(self.names())}, got {name!r}"
        if isinstance(name, str):
            close = difflib.get_close_matches(name, self._entries, n=1, cutoff=0.6)
            if close:
                msg += f"; did you mean {close[0]!r}?"
        raise UnknownNameError(msg)

    def __getitem__(self, name: str) -> T:
        """``registry[name]``: as :meth:`get` (the error is also a :class:`KeyError`)."""
        return self.get(name)

    def keys(self) -> tuple[str, ...]:
        """Registered names, in registration order (as :meth:`names`)."""
        return self.names()

    def values(self) -> tuple[T, ...]:
        """Registered entries, in registration order."""
        return tuple(self._entries.values())

    def names(self) -> tuple[str, ...]:
        """Registered names, in registration order."""
        return tuple(self._entries)

    def items(self) -> Iterator[tuple[str, T]]:
        """``(name, entry)`` pairs, in registration order."""
        return iter(self._entries.items())

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"<Registry of {len(self)} {self.kind}(s): {', '.join(self._entries)}>"


def _origin(entry: object) -> tuple[str, str, object] | None:
    """Where ``entry`` was defined: module, qualified name (and the bound parameters of a
    ``functools.partial``); ``None`` for an object with no definition site."""
    target = entry.func if isinstance(entry, functools.partial) else entry
    qualname = getattr(target, "__qualname__", None)
    if qualname is None:
        return None
    return (getattr(target, "__module__", "?"), qualname, getattr(entry, "keywords", None))


def _where(entry: object) -> str:
    origin = _origin(entry)
    return repr(entry) if origin is None else f"{origin[0]}.{origin[1]}"


def _redefinition(old: object, new: object) -> bool:
    """Whether ``new`` is ``old`` defined again (a notebook cell run twice, a reloaded
    module), not another object that happens to want the same name."""
    origin = _origin(old)
    return origin is not None and origin == _origin(new)
