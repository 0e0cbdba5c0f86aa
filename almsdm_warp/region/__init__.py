"""Contact and region: where the probe touches, and the rings of neighbours grown from there."""

from .contact import ContactQuery, Contacts, find_contacts
from .region import Region, ring_distances

__all__ = ["ContactQuery", "Contacts", "Region", "find_contacts", "ring_distances"]
