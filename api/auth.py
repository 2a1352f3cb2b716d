"""The API token (``AIRPUFF_API_TOKEN``): the bearer header of API clients and the session cookie
of the browser pages.

A browser cannot send an ``Authorization`` header on a link or an ``<img>``, so the pages' login
form (``POST /login``) checks the token once and sets an HttpOnly, SameSite=Strict cookie.  The
cookie holds ``HMAC-SHA256(token, SESSION_LABEL)``, not the token itself: it opens the pages and
the API's read-only (GET) endpoints, and changing the token invalidates it.  Requests that change
state through the API (POST, DELETE) still need the bearer header; the pages' own forms check the
cookie and the request's origin (``same_origin``).  Every comparison is constant-time.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from urllib.parse import urlsplit

from starlette.requests import Request

SESSION_COOKIE = "airpuff_session"
SESSION_LABEL = b"airpuff browser session v1"
SAFE_METHODS = ("GET", "HEAD")


def session_value(token: str) -> str:
    """The cookie value that stands for ``token``: HMAC-SHA256(token, SESSION_LABEL), hex."""
    return hmac.new(token.encode(), SESSION_LABEL, hashlib.sha256).hexdigest()


def token_matches(candidate: str | None, token: str) -> bool:
    """Constant-time comparison of a token typed or sent by a client with the server's."""
    return candidate is not None and secrets.compare_digest(candidate.encode(), token.encode())


def session_ok(request: Request, token: str) -> bool:
    """True if the request carries the session cookie of ``token``."""
    cookie = request.cookies.get(SESSION_COOKIE)
    return cookie is not None and secrets.compare_digest(cookie.encode(),
                                                         session_value(token).encode())


def bearer_ok(request: Request, token: str) -> bool:
    """True if the request carries ``Authorization: Bearer <token>``."""
    scheme, _, credentials = request.headers.get("authorization", "").partition(" ")
    return scheme.lower() == "bearer" and token_matches(credentials.strip(), token)


def same_origin(request: Request) -> bool:
    """True unless the browser says the request comes from another site (Origin or Referer with a
    different host:port).  A second guard, after SameSite=Strict, for the pages' POST forms."""
    source = request.headers.get("origin") or request.headers.get("referer")
    if not source or source == "null":
        return source is None
    host = request.headers.get("host", "")
    return urlsplit(source).netloc == host
