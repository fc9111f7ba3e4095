"""Deprecated location (moved to `bsjax.basis`); kept until every caller imports `bsjax.basis`."""

from bsjax.basis._surface import Blending as Blending
