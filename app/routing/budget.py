"""The routing time budget of one request (``UGVMAP_ROUTING_TIME_BUDGET_S``), checked inside the
loops of its work, so the budget bounds the request's wall time and not one stage of it.

Why: a 5,000-point match checked the budget only in its Viterbi loop, and the stages around it
(each point's candidates, the legs between matched points, shaping them into routes) took
three times as long again, so the request answered ``TooBig`` after 30-46 s under load
(issue 33).
"""

from __future__ import annotations

import time

from app.errors import TooBigError
from app.routing.settings import routing_settings


class Budget:
    """The time left to one request's ``what``; :meth:`check` raises ``TooBig`` once spent,
    with ``hint`` telling the client what to ask for instead."""

    def __init__(self, what: str, hint: str) -> None:
        self.what, self.hint = what, hint
        self.seconds = routing_settings().time_budget_s
        self.ends = time.monotonic() + self.seconds

    def check(self, progress: str = "") -> None:
        """Raise ``TooBig`` when the budget is spent (``progress``: how far the work got)."""
        if time.monotonic() > self.ends:
            raise TooBigError(f"{self.what} took longer than the time budget "
                              f"({self.seconds:g} s){progress}: {self.hint}")
