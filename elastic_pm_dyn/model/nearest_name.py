"""The existing name nearest a misspelt one, for a refusal that says what was meant."""

from __future__ import annotations

import difflib
from collections.abc import Iterable


def nearest(name: str, names: Iterable[str]) -> str:
    """``" (nearest: 'spherical_crank')"``, or ``""`` where no name is close (difflib's ratio
    below 0.6: a guess would mislead more than help)."""
    found = difflib.get_close_matches(name, list(names), n=1, cutoff=0.6)
    return f" (nearest: {found[0]!r})" if found else ""
