"""Scene builders (a small, documented function each)."""

from .basic import hanging_cloth, tablecloth

__all__ = ["hanging_cloth", "tablecloth"]
