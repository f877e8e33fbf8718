"""Bounded lanes for heavy requests: a few run at once per kind, a few more wait, the rest are
told at once to come back later.

Why: 50 clients mixing whole-network Lanelet2 exports, 5,000-point matches, 100 x 100 tables
and isochrones took every worker thread and most of the CPU, so a tile waited 4 s and a single
feature 9.8 s, and each heavy request itself took a minute (issue 33). A lane per kind of heavy
work keeps ``running`` of them working, lets ``waiting`` more queue for a slot, and refuses the
next one straight away with :class:`~app.errors.ServiceBusyError` (503 with ``Retry-After``)
rather than letting it pile up: a client learns within milliseconds, the work in progress
finishes sooner, and light requests (tiles, single items, ``/healthz``) keep their threads.

The kinds also share ``total`` slots (one by default): on this 2-core box six heavy requests
at once in a worker (one per kind) held the GIL so much that a single feature took 1.2 s at the
99th percentile and a 503 came after more than a second; one at a time per worker leaves the
worker's event loop its share, and the cores are as busy with one per worker (measured with
``bench/heavy_mix.py``, docs/performance.md).

A routing request takes its place in the lane on arrival (:func:`held_on_arrival`, a route
dependency), before its points are parsed or its network's version read: when it was only
checked on arrival and the place taken later, a burst of 50 clients at once (each worker's
lanes empty) let every request of the burst past the check, each parsed its 5,000 points on
the event loop, and then most were refused: 12-33 of the 503s came after 2.4-4.7 s on a quiet
box (``bench/heavy_mix.py``).

A lane belongs to the event loop it is used on (one per worker; tests start several): asyncio's
semaphore may only be awaited on one loop.
"""

from __future__ import annotations

import asyncio
import weakref
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from contextvars import ContextVar
from functools import lru_cache
from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from app.errors import ServiceBusyError

Kind = Literal["lanelet2", "match", "table", "trip", "isochrone", "items"]


class LaneSettings(BaseSettings):
    """Per worker and per kind of heavy request, from ``UGVMAP_HEAVY_*`` variables."""

    model_config = SettingsConfigDict(env_prefix="UGVMAP_HEAVY_", extra="ignore")

    running: int = Field(default=1, ge=1)  # at once; more only helps with more cores
    total: int = Field(default=1, ge=1)  # at once, all kinds together
    waiting: int = Field(default=4, ge=0)  # queued for a slot; beyond them: 503
    retry_after_s: int = Field(default=2, ge=1)  # the 503's Retry-After


_HELD: ContextVar[frozenset[str]] = ContextVar("ugvmap_lanes_held", default=frozenset())
"""The kinds whose slot the running request holds: its work's own :meth:`Lane.slot` inside the
slot taken on arrival is that same slot, not a second one."""


@lru_cache(maxsize=1)
def lane_settings() -> LaneSettings:
    """Read once per process (cached); tests clear it to try other limits."""
    return LaneSettings()


class Lane:
    """One kind's slots and queue on one event loop; a slot also takes one of the slots all
    kinds of the loop share (``shared``; by default the lane's own)."""

    def __init__(self, kind: Kind, settings: LaneSettings,
                 shared: asyncio.Semaphore | None = None) -> None:
        self.kind = kind
        self._shared = asyncio.Semaphore(settings.total) if shared is None else shared
        self.running = settings.running
        self.capacity = settings.waiting
        self.retry_after_s = settings.retry_after_s
        self._slots = asyncio.Semaphore(settings.running)
        self.waiting = 0

    def refuse_when_full(self) -> None:
        """Raise :class:`ServiceBusyError` when every slot is taken and the queue is full."""
        if self._slots.locked() and self.waiting >= self.capacity:
            raise ServiceBusyError(
                f"the server is busy with {self.kind} requests ({self.running} running, "
                f"{self.waiting} waiting): try again in {self.retry_after_s} s",
                retry_after_s=self.retry_after_s)

    @asynccontextmanager
    async def slot(self) -> AsyncIterator[None]:
        """Hold one of the lane's slots for the block; queue for one when all are taken and
        the queue has room, else raise :class:`ServiceBusyError` at once. Inside a slot of
        the same kind this request already holds, it is that slot."""
        if self.kind in _HELD.get():
            yield
            return
        self.refuse_when_full()
        self.waiting += 1
        try:
            await self._slots.acquire()
            try:
                await self._shared.acquire()
            except BaseException:
                self._slots.release()
                raise
        finally:
            self.waiting -= 1
        _HELD.set(_HELD.get() | {self.kind})
        try:
            yield
        finally:
            # set, not reset: a dependency's exit may run in another context than its entry
            _HELD.set(_HELD.get() - {self.kind})
            self._shared.release()
            self._slots.release()


class _Lanes:
    """The lanes of one event loop and the slots they share."""

    def __init__(self, settings: LaneSettings) -> None:
        self.settings = settings
        self.shared = asyncio.Semaphore(settings.total)
        self.by_kind: dict[Kind, Lane] = {}


_LANES: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, _Lanes] = \
    weakref.WeakKeyDictionary()


def lane(kind: Kind) -> Lane:
    """The lane of ``kind`` on the running event loop (made on first use)."""
    loop = asyncio.get_running_loop()
    lanes = _LANES.get(loop)
    if lanes is None:
        lanes = _LANES[loop] = _Lanes(lane_settings())
    if kind not in lanes.by_kind:
        lanes.by_kind[kind] = Lane(kind, lanes.settings, lanes.shared)
    return lanes.by_kind[kind]


def held_on_arrival(kind: Kind) -> Callable[[], AsyncIterator[None]]:
    """A route dependency holding a slot of ``kind``'s lane for the whole request, taken (or
    queued for, or refused with 503) as the request arrives, before its points are parsed (of
    a POST, FastAPI has only decoded the JSON): the work's own :meth:`Lane.slot` then finds it
    held."""
    async def lane_slot() -> AsyncIterator[None]:
        async with lane(kind).slot():
            yield

    return lane_slot
