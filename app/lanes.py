"""Bounded lanes for heavy requests: a few run at once per kind, a few more wait, the rest are
told at once to come back later.

Why: 50 clients mixing whole-network Lanelet2 exports, 5,000-point matches, 100 x 100 tables
and isochrones took every worker thread and most of the CPU, so a tile waited 4 s and a single
feature 9.8 s, and each heavy request itself took a minute (issue 33). A lane per kind of heavy
work keeps ``running`` of them working, lets ``waiting`` more queue for a slot, and refuses the
next one straight away with :class:`~app.errors.ServiceBusyError` (503 with ``Retry-After``)
rather than letting it pile up: a client learns within milliseconds, the work in progress
finishes sooner, and light requests (tiles, single items, ``/healthz``) keep their threads.

A lane belongs to the event loop it is used on (one per worker; tests start several): asyncio's
semaphore may only be awaited on one loop.
"""

from __future__ import annotations

import asyncio
import weakref
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
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
    waiting: int = Field(default=4, ge=0)  # queued for a slot; beyond them: 503
    retry_after_s: int = Field(default=2, ge=1)  # the 503's Retry-After


@lru_cache(maxsize=1)
def lane_settings() -> LaneSettings:
    """Read once per process (cached); tests clear it to try other limits."""
    return LaneSettings()


class Lane:
    """One kind's slots and queue on one event loop."""

    def __init__(self, kind: Kind, settings: LaneSettings) -> None:
        self.kind = kind
        self.running = settings.running
        self.capacity = settings.waiting
        self.retry_after_s = settings.retry_after_s
        self._slots = asyncio.Semaphore(settings.running)
        self.waiting = 0

    @asynccontextmanager
    async def slot(self) -> AsyncIterator[None]:
        """Hold one of the lane's slots for the block; queue for one when all are taken and
        the queue has room, else raise :class:`ServiceBusyError` at once."""
        if self._slots.locked() and self.waiting >= self.capacity:
            raise ServiceBusyError(
                f"the server is busy with {self.kind} requests ({self.running} running, "
                f"{self.waiting} waiting): try again in {self.retry_after_s} s",
                retry_after_s=self.retry_after_s)
        self.waiting += 1
        try:
            await self._slots.acquire()
        finally:
            self.waiting -= 1
        try:
            yield
        finally:
            self._slots.release()


_LANES: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, dict[Kind, Lane]] = \
    weakref.WeakKeyDictionary()


def lane(kind: Kind) -> Lane:
    """The lane of ``kind`` on the running event loop (made on first use)."""
    lanes = _LANES.setdefault(asyncio.get_running_loop(), {})
    if kind not in lanes:
        lanes[kind] = Lane(kind, lane_settings())
    return lanes[kind]
