"""The ``growth`` section: identification, campaign and Monte-Carlo cost as the work grows."""

from __future__ import annotations

__all__ = ["growth_section"]


def growth_section(quick: bool = False, repeats: int = 5) -> dict:
    try:
        import twin.estimator  # noqa: F401
    except ImportError as e:
        return {"missing": f"twin.estimator not on this branch ({e}); nothing measured"}
    return {"missing": "growth measurement not implemented yet"}
