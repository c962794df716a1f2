"""Chemical formulas to atom counts: ``"Bi4Ge3O12"``, ``"Cd0.9Zn0.1Te"``, ``"Ca(OH)2"``.

A formula is a sequence of element symbols (an upper-case letter and any lower-case ones) and
parenthesised groups, each optionally followed by a positive decimal count (``2``, ``0.9``,
``.5``); a group's count multiplies every count inside it, and a repeated element's counts add.
No spaces, no hydrate dots, no isotopes: the formulas fisx accepted, which rotmod used before.
Whether a symbol is a known element is the caller's business (it owns the element table).
"""

from __future__ import annotations

import re

from rotmod.errors import MaterialError

__all__ = ["atom_counts"]

# One token: an element symbol, a count, or a parenthesis.
_TOKEN = re.compile(r"(?P<symbol>[A-Z][a-z]*)|(?P<count>\d+(?:\.\d*)?|\.\d+)|(?P<paren>[()])")


def _tokens(formula: str) -> list[tuple[str, str]]:
    out, pos = [], 0
    while pos < len(formula):
        m = _TOKEN.match(formula, pos)
        if m is None:
            raise MaterialError(f"unexpected character {formula[pos]!r} at position {pos}")
        kind = m.lastgroup
        assert kind is not None  # every alternative is a named group
        out.append((kind, m.group()))
        pos = m.end()
    return out


def atom_counts(formula: str) -> dict[str, float]:
    """Atoms of each symbol in ``formula``, in order of first appearance.

    Parameters
    ----------
    formula : str
        A chemical formula (``"PbWO4"``, ``"Mg(NO3)2"``).

    Returns
    -------
    dict
        Symbol -> number of atoms (positive; fractional counts allowed).

    Raises
    ------
    MaterialError
        Not a formula; the message says what is wrong (and where), without the formula,
        which the caller names.
    """
    tokens = _tokens(formula)
    if not tokens:
        raise MaterialError("empty formula")
    # A scintillator's name carries its activator in parentheses, NaI(Tl), CsI(Na): read as a
    # formula that is one activator atom per host molecule (Tl would be 58 % of NaI(Tl)'s
    # mass, its attenuation 24 % high at 662 keV), while the real dopant is ~0.1 % and does
    # not change the attenuation.  A final one-element group without a count says that.
    if (len(tokens) >= 4 and tokens[-1] == ("paren", ")") and tokens[-3] == ("paren", "(")
            and tokens[-2][0] == "symbol"):
        host = "".join(t for _, t in tokens[:-3])
        raise MaterialError(
            f"'({tokens[-2][1]})' reads as an activator (a scintillator's dopant): write the "
            f"host formula {host!r}; a dopant at ~0.1 % does not change the attenuation")
    # A stack of groups: the formula, then one per open parenthesis.  An element or a closed
    # group is added to the enclosing group once its count is known (the next token), so a
    # repeated element's counts add in order of appearance, as fisx added them.
    stack: list[dict[str, float]] = [{}]
    pending: dict[str, float] | None = None
    for kind, text in tokens:
        if kind == "count":
            if pending is None:
                raise MaterialError(f"count {text!r} follows no element or group")
            n = float(text)
            if not n > 0:
                raise MaterialError(f"count {text!r} must be > 0")
            _add(stack[-1], pending, n)
            pending = None
            continue
        if pending is not None:
            _add(stack[-1], pending, 1.0)
            pending = None
        if kind == "symbol":
            pending = {text: 1.0}
        elif text == "(":
            stack.append({})
        else:
            if len(stack) == 1:
                raise MaterialError("')' without a matching '('")
            pending = stack.pop()
            if not pending:
                raise MaterialError("empty parentheses '()'")
    if len(stack) > 1:
        raise MaterialError("'(' without a matching ')'")
    if pending is not None:
        _add(stack[0], pending, 1.0)
    return stack[0]


def _add(into: dict[str, float], counts: dict[str, float], times: float) -> None:
    for symbol, n in counts.items():
        into[symbol] = into.get(symbol, 0.0) + n * times
