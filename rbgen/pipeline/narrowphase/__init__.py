"""Narrowphase: contact manifolds from broadphase pairs (see `narrowphase`)."""
from .narrowphase import Narrowphase, find_contacts, kinds_for

__all__ = ["Narrowphase", "find_contacts", "kinds_for"]
