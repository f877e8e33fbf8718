"""ASGI middleware that changes only how a response starts (its status line and headers),
never its body: the shape :mod:`app.api.wire` and the security headers of
:mod:`app.api.middleware` share."""

from __future__ import annotations

from starlette.types import Message, Receive, Scope, Send

from app.api.asgi import HttpMiddleware


class ResponseStartMiddleware(HttpMiddleware):
    """Pass every HTTP request on and hand each ``http.response.start`` message to
    :meth:`start` before it is sent."""

    def start(self, message: Message) -> Message:
        """The start message as it should be sent."""
        raise NotImplementedError

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Run the app; rewrite its start message on the way out."""

        async def started(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = self.start(message)
            await send(message)

        await self.app(scope, receive, started)
