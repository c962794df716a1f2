"""File input and output (FITS event lists and folded profiles; more formats elsewhere)."""

from rotmod.io.events import read_events, read_folded, write_events, write_folded

__all__ = ["read_events", "read_folded", "write_events", "write_folded"]
