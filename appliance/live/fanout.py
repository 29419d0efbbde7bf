"""Several live views fed as one: the Rerun view and the operator's page.

The publisher and the leak monitor push each item once; :class:`ViewFanout` hands it to
every view (each keeps only its newest items and never blocks, so neither waits on the
other).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["ViewFanout", "views_of"]


class ViewFanout:
    """``push`` and ``wants_pictures`` over several views (each has both methods)."""

    def __init__(self, views: Sequence[Any]) -> None:
        self.views = list(views)

    def push(self, item: Any) -> bool:
        """Hand ``item`` to every view; True when at least one took it."""
        took = [view.push(item) for view in self.views]
        return any(took)

    def wants_pictures(self) -> bool:
        """Whether any view would show a picture now (the workers then send full fields)."""
        return any(view.wants_pictures() for view in self.views)


def views_of(*views: Any) -> Any:
    """The one object to push to: None without views, the view itself when there is one."""
    present = [v for v in views if v is not None]
    if not present:
        return None
    return present[0] if len(present) == 1 else ViewFanout(present)
