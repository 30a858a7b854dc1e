"""Team tokens (only their hashes are stored) and signed, expiring download links."""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import secrets
import time

TOKEN_PREFIX = "ff3d_"


def new_team_token() -> str:
    """A fresh bearer token: 256 random bits, shown to the team once."""
    return TOKEN_PREFIX + secrets.token_urlsafe(32)


def hash_token(token: str) -> str:
    """SHA-256 hex digest of a token.

    Tokens carry 256 random bits, so a fast unsalted hash is enough: there is no
    dictionary to attack, and the digest can be looked up by equality.
    """
    return hashlib.sha256(token.encode()).hexdigest()


def tokens_equal(given: str, expected: str) -> bool:
    """Constant-time comparison (for the admin token)."""
    return hmac.compare_digest(given.encode(), expected.encode())


def sign_payload(payload: dict[str, str], key: str, expires_s: int) -> str:
    """An opaque URL-safe string carrying `payload` until ``now + expires_s``."""
    body = dict(payload, exp=str(int(time.time()) + expires_s))
    raw = base64.urlsafe_b64encode(json.dumps(body, sort_keys=True).encode()).decode()
    return f"{raw}.{_mac(raw, key)}"


def verify_payload(signed: str, key: str) -> dict[str, str] | None:
    """The payload of a string made by `sign_payload`, or None if forged or expired."""
    raw, _, mac = signed.partition(".")
    if not hmac.compare_digest(mac.encode(), _mac(raw, key).encode()):
        return None
    try:
        body = json.loads(base64.urlsafe_b64decode(raw.encode()))
    except ValueError:
        return None
    if not isinstance(body, dict) or int(body.pop("exp", 0)) < time.time():
        return None
    return {str(k): str(v) for k, v in body.items()}


def _mac(raw: str, key: str) -> str:
    return hmac.new(key.encode(), raw.encode(), hashlib.sha256).hexdigest()
