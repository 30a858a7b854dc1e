"""Security headers on every response (a plain ASGI middleware: no body buffering).

The pages load scripts only from the app's own static files (no inline script, no CDN),
so the Content-Security-Policy can forbid everything else. Exceptions, and why:
``'wasm-unsafe-eval'`` lets the upload page's hashing library compile its WebAssembly;
``worker-src blob:`` lets ReDoc start its search worker;
``style-src 'unsafe-inline'`` is for the API docs (Swagger UI and ReDoc set inline
styles; our own pages have none, and styles cannot run code); the object store's
origin is allowed for presigned uploads (``connect-src``) and report plots
(``img-src``), which the browser fetches from the bucket directly.
"""

from __future__ import annotations

from urllib.parse import urlsplit

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from services.core.settings import Settings


def storage_origin(settings: Settings) -> str | None:
    """The origin browsers reach the object store at, or None for local storage."""
    if settings.storage_backend != "s3":
        return None
    endpoint = settings.s3_public_endpoint_url or settings.s3_endpoint_url
    if endpoint is None:
        return "https://*.amazonaws.com"
    parts = urlsplit(endpoint)
    return f"{parts.scheme}://{parts.netloc}"


def content_security_policy(settings: Settings) -> str:
    store = storage_origin(settings)
    extra = f" {store}" if store else ""
    return "; ".join(
        [
            "default-src 'self'",
            "script-src 'self' 'wasm-unsafe-eval'",
            "worker-src 'self' blob:",
            "style-src 'self' 'unsafe-inline'",
            f"img-src 'self' data: blob:{extra}",
            f"connect-src 'self'{extra}",
            "font-src 'self' data:",
            "object-src 'none'",
            "base-uri 'self'",
            "form-action 'self'",
            "frame-ancestors 'none'",
        ]
    )


class SecurityHeaders:
    """Adds CSP, frame, nosniff and referrer headers to every HTTP response."""

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.headers = [
            (b"content-security-policy", content_security_policy(settings).encode()),
            (b"x-frame-options", b"DENY"),
            (b"x-content-type-options", b"nosniff"),
            (b"referrer-policy", b"no-referrer"),
            (b"cross-origin-opener-policy", b"same-origin"),
        ]

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), *self.headers]
            await send(message)

        await self.app(scope, receive, with_headers)
