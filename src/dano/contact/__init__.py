"""Probabilistic contact between DANOs and other bodies (paper §IV)."""

from .force import contact_wrench, generalized_force
from .params import ContactParams, smooth_direction

__all__ = ["ContactParams", "contact_wrench", "generalized_force", "smooth_direction"]
