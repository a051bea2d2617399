"""The old home of the atomic writes, kept while the upper layers that import it from here are
rewritten (issue 19; tests/test_layering.py lists them): the writes live in :mod:`softvr.files`."""

from softvr.files import atomic_output, write_json

__all__ = ["atomic_output", "write_json"]
