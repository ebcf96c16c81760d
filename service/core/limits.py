"""Request body size limit, enforced while the body streams in (before it reaches disk)."""

from __future__ import annotations

import asyncio
import json

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from api_schemas import PROBLEM_MEDIA_TYPE
from service.core.problems import ProblemError

__all__ = ["BodyLimitMiddleware", "BodyTimeout", "BodyTooLarge"]


class BodyTooLarge(ProblemError):
    """The request body exceeds the configured limit (413)."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than {limit} bytes",
                         title="Payload too large")


def _too_large(exc: BaseException) -> bool:
    if isinstance(exc, BodyTooLarge):
        return True
    if isinstance(exc, BaseExceptionGroup):
        return any(_too_large(e) for e in exc.exceptions)
    return _too_large(exc.__cause__) if exc.__cause__ is not None else False


class BodyTimeout(ProblemError):
    """No part of the request body arrived for too long (408), e.g. a Content-Length larger
    than the body sent."""

    def __init__(self, seconds: float) -> None:
        super().__init__(408, f"the request body stopped arriving ({seconds:g} s without data)",
                         title="Request timeout", headers={"Connection": "close"})


class BodyLimitMiddleware:
    """Refuse bodies over ``max_bytes``: at once by Content-Length, else while reading; and
    bodies that stall for ``timeout`` seconds before their end (408)."""

    def __init__(self, app: ASGIApp, max_bytes: int, timeout: float = 60.0) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.timeout = timeout

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        declared = headers.get(b"content-length", b"").decode("latin-1")
        if declared.isdigit() and int(declared) > self.max_bytes:
            await self._refuse(scope, send)
            return
        seen = 0
        complete = False

        async def limited() -> Message:
            nonlocal seen, complete
            if complete:  # after the body: waits for a disconnect, however long
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), self.timeout)
            except TimeoutError:
                raise BodyTimeout(self.timeout) from None
            complete = not message.get("more_body", False)
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                raise BodyTooLarge(self.max_bytes)
            return message

        started = False

        async def send_started(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, limited, send_started)
        except Exception as exc:
            # Normally the app's handler already answered 413; this is the fallback for a
            # layer that wrapped the exception (e.g. in an ExceptionGroup).
            if started or not _too_large(exc):
                raise
            await self._refuse(scope, send)

    async def _refuse(self, scope: Scope, send: Send) -> None:
        body = json.dumps({"type": "about:blank", "title": "Payload too large", "status": 413,
                           "detail": f"request body larger than {self.max_bytes} bytes",
                           "instance": scope.get("path")}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                                (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})
