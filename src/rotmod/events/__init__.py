"""Time-tagged event lists, good-time intervals and folding modulo the rotation period."""

from rotmod.events.eventlist import EventList
from rotmod.events.folding import FoldedProfiles, exposure_per_bin, fold
from rotmod.events.gti import check_gti

__all__ = ["EventList", "FoldedProfiles", "check_gti", "exposure_per_bin", "fold"]
