"""The ``pipeline`` section: seconds per stereo pair for render, detect, triangulate, against bare rendering."""

from __future__ import annotations

__all__ = ["pipeline_section"]


def pipeline_section(quick: bool = False) -> dict:
    try:
        import twin.instrument  # noqa: F401
        import twin.world  # noqa: F401
    except ImportError as e:
        return {"missing": f"twin.world / twin.instrument not on this branch ({e}); nothing measured"}
    return {"missing": "pipeline measurement not implemented yet"}
