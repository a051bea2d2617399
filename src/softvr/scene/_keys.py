"""The nearest known key of a misspelt one, for every file softvr reads tables from."""

import difflib

__all__ = ["known_key"]


def known_key(valid, key) -> str:
    """What was expected instead of the unknown ``key``: the nearest of the ``valid`` keys when
    one is near (difflib's ratio >= 0.6), else all of them."""
    valid = sorted(valid)
    near = difflib.get_close_matches(str(key), valid, n=1, cutoff=0.6)
    return f"a known key (did you mean {near[0]!r}?)" if near else f"one of {', '.join(valid)}"
