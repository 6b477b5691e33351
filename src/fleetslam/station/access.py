"""Who may open the console's WebSocket (pure): the holder of the console's token, from the console's own page.

The WebSocket drives robots and releases e-stops, so it is not open to whoever reaches the port:

- **token**: a random secret made when the console starts (or given by the operator), part of the URL the console
  prints (``http://host:port/?token=…``); the page passes it on to the WebSocket. A page of another site cannot
  know it, and neither can a DNS-rebinding page that reaches the port under a name of its own.
- **origin**: a browser names the page that opens a WebSocket in its ``Origin`` header; a page from anywhere but the
  console itself (or an origin the operator allowed) is refused even with the token. Programs that are not browsers
  send no Origin and need only the token.

Refusals say why, so an operator who mistyped the URL knows what to fix.
"""

from __future__ import annotations

import hmac
import secrets
from collections.abc import Iterable
from dataclasses import dataclass, field
from urllib.parse import urlsplit


def new_token() -> str:
    """A fresh random token (128 bits, URL-safe)."""
    return secrets.token_urlsafe(16)


def _origin_of(url: str) -> str:
    parts = urlsplit(url.strip())
    return f"{parts.scheme.lower()}://{parts.netloc.lower()}"


@dataclass(frozen=True)
class ConsoleAccess:
    """The console's token and the origins besides its own whose pages may open the WebSocket."""

    token: str
    allowed_origins: frozenset[str] = field(default_factory=frozenset)

    @classmethod
    def create(cls, token: str | None = None, allowed_origins: Iterable[str] = ()) -> ConsoleAccess:
        """Access with ``token`` (a new random one when None) and ``allowed_origins`` (``scheme://host:port``)."""
        if token is not None and len(token) < 8:
            raise ValueError(f"console token must have at least 8 characters, got {len(token)}")
        return cls(token or new_token(), frozenset(_origin_of(o) for o in allowed_origins))

    def refusal(self, *, token: str | None, origin: str | None, host: str | None, secure: bool = False) -> str | None:
        """Why a WebSocket request is refused (None: it is allowed). ``host`` is the request's Host header."""
        if not token:
            return "no console token: open the URL the console printed (it ends in ?token=...)"
        if not hmac.compare_digest(token.encode(), self.token.encode()):
            return "wrong console token: open the URL the console printed"
        if origin is None:
            return None  # not a browser: the token is all it can show
        own = f"{'https' if secure else 'http'}://{(host or '').lower()}"
        if _origin_of(origin) not in {own, *self.allowed_origins}:
            return f"a page from {origin!r} may not drive robots (the console serves {own!r})"
        return None
