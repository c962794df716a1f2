"""Bursts: transients found in the event stream, localised and measured.

A burst lasts a few rotations of the mask or less, so its counts are not folded: the
likelihood is that of the time-tagged counts in short bins, with the burst's light curve in
the model (:class:`rotmod.response.UnfoldedResponse`), and the background fitted outside
the burst.  See ``docs/bursts.md``.
"""

__all__: list[str] = []
