"""The ISA-L gzip middleware gives what Starlette's gives: one gzip stream a client inflates
to the same bytes, whole or streamed in chunks, and small or excluded bodies untouched."""

from __future__ import annotations

import os
from collections.abc import Iterator

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route
from starlette.testclient import TestClient

from app.api.compression import IsalGZipMiddleware

BODY = b'{"coordinates": [[1.5211, 42.5063], [1.5212, 42.5064]], "name": "Avinguda"}' * 400


def _app() -> Starlette:
    def whole(request: Request) -> Response:
        return Response(BODY, media_type="application/json")

    def streamed(request: Request) -> StreamingResponse:
        def chunks() -> Iterator[bytes]:
            for k in range(0, len(BODY), 7_000):
                yield BODY[k:k + 7_000]
        return StreamingResponse(chunks(), media_type="application/json")

    def small(request: Request) -> Response:
        return Response(b'{"status": "ok"}', media_type="application/json")

    def png(request: Request) -> Response:
        return Response(os.urandom(4_000), media_type="image/png")

    app = Starlette(routes=[Route("/whole", whole), Route("/streamed", streamed),
                            Route("/small", small), Route("/png", png)])
    app.add_middleware(IsalGZipMiddleware, minimum_size=500)
    return app


def test_whole_and_streamed_bodies_inflate_to_the_same_bytes() -> None:
    with TestClient(_app()) as client:
        for path in ("/whole", "/streamed"):
            r = client.get(path, headers={"Accept-Encoding": "gzip"})
            assert r.headers["content-encoding"] == "gzip", path
            assert "Accept-Encoding" in r.headers["vary"]
            assert r.content == BODY  # httpx inflates it
        size = int(client.get("/whole", headers={"Accept-Encoding": "gzip"})
                   .headers["content-length"])
        assert size < len(BODY) // 20


def test_small_excluded_or_unaccepted_bodies_are_not_compressed() -> None:
    with TestClient(_app()) as client:
        assert "content-encoding" not in client.get(
            "/small", headers={"Accept-Encoding": "gzip"}).headers
        assert "content-encoding" not in client.get(
            "/png", headers={"Accept-Encoding": "gzip"}).headers
        plain = client.get("/whole", headers={"Accept-Encoding": "identity"})
        assert "content-encoding" not in plain.headers and plain.content == BODY
