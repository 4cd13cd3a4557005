"""The content-addressed cache of trained materials (issue #10): see :mod:`bcfpipe.cache.store`."""
from bcfpipe.cache.store import ENV, Cache, CacheError, Entry, EntryInfo, Lookup, default_root

__all__ = ["Cache", "CacheError", "Entry", "EntryInfo", "Lookup", "default_root", "ENV"]
