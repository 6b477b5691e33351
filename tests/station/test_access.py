"""Who may open the console's WebSocket: the token, then the page's origin."""

from __future__ import annotations

import pytest

from fleetslam.station.access import ConsoleAccess


def test_token_and_origin_rules() -> None:
    access = ConsoleAccess.create("s3cret-token", ["https://ops.example:8443/"])
    allow = {"host": "127.0.0.1:8080"}
    assert access.refusal(token="s3cret-token", origin="http://127.0.0.1:8080", **allow) is None
    assert access.refusal(token="s3cret-token", origin="HTTP://127.0.0.1:8080", **allow) is None
    assert access.refusal(token="s3cret-token", origin="https://ops.example:8443", **allow) is None
    assert access.refusal(token="s3cret-token", origin=None, **allow) is None  # a program, not a browser
    assert "no console token" in str(access.refusal(token=None, origin="http://127.0.0.1:8080", **allow))
    assert "wrong console token" in str(access.refusal(token="s3cret-tokem", origin=None, **allow))
    refusal = access.refusal(token="s3cret-token", origin="http://evil.example", **allow)
    assert refusal is not None and "'http://evil.example' may not drive robots" in refusal
    # the console over https is another origin than over http
    assert access.refusal(token="s3cret-token", origin="http://127.0.0.1:8080", secure=True, **allow) is not None


def test_tokens_are_random_and_not_trivially_short() -> None:
    assert ConsoleAccess.create().token != ConsoleAccess.create().token
    assert len(ConsoleAccess.create().token) >= 20
    with pytest.raises(ValueError, match="at least 8 characters"):
        ConsoleAccess.create("1234")
