"""Our calibrators as methods of the grid (default estimator, LM, C-LM, separation), from ``twin.estimator``."""

from __future__ import annotations

from .harness import Method

__all__ = ["ours_methods", "ours_missing"]


def ours_methods() -> list[Method]:
    """Our methods, when ``twin.estimator`` provides them (empty until the estimator branch has landed)."""
    try:
        import twin.estimator  # noqa: F401
    except ImportError:
        return []
    return []


def ours_missing() -> str | None:
    """What of ours could not be measured, or ``None``."""
    try:
        import twin.estimator  # noqa: F401
    except ImportError:
        return "twin.estimator does not exist on this branch yet: our columns are missing"
    return None
