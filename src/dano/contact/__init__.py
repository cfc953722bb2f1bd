"""Probabilistic contact between DANOs and other bodies (paper §IV).

One module per pair kind (:mod:`.plane`, :mod:`.primitive`, :mod:`.dano_pair`) and per
contact model (:mod:`.centroid`, :mod:`.per_sample`); they register themselves in
:data:`PAIR_KINDS` and :data:`CONTACT_MODELS` (:mod:`.base`), so adding one is a new module.
"""

from . import centroid, dano_pair, per_sample, plane, primitive  # noqa: F401  (register)
from .base import (CONTACT_MODELS, PAIR_KINDS, ContactModel, PairGeometry, PairKind, contact_model,
                   register_contact_model, register_pair_kind, surface_occupancy, world_frame, world_points)
from .centroid import Centroid
from .law import pair_wrench, sample_forces
from .params import ContactParams, smooth_direction
from .per_sample import PerSample
from .samples import Samples

__all__ = ["CONTACT_MODELS", "PAIR_KINDS", "Centroid", "ContactModel", "ContactParams", "PairGeometry", "PairKind",
           "PerSample", "Samples", "contact_model", "pair_wrench", "register_contact_model", "register_pair_kind",
           "sample_forces", "smooth_direction", "surface_occupancy", "world_frame", "world_points"]
