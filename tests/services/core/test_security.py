"""Team tokens and signed download links."""

from __future__ import annotations

from services.core.security import (
    hash_token,
    new_team_token,
    sign_payload,
    tokens_equal,
    verify_payload,
)


def test_tokens_are_unique_and_hashed() -> None:
    tokens = {new_team_token() for _ in range(100)}
    assert len(tokens) == 100
    token = tokens.pop()
    assert token.startswith("ff3d_") and len(token) > 40
    assert hash_token(token) == hash_token(token) != hash_token(token + "x")
    assert len(hash_token(token)) == 64 and token not in hash_token(token)
    assert tokens_equal(token, token) and not tokens_equal(token, token[:-1])


def test_signed_payload_round_trip_and_forgery() -> None:
    signed = sign_payload({"key": "jobs/1/trajectories.csv"}, "secret", expires_s=60)
    assert verify_payload(signed, "secret") == {"key": "jobs/1/trajectories.csv"}
    assert verify_payload(signed, "other-secret") is None
    mac = signed.split(".")[1]
    forged = sign_payload({"key": "jobs/2/trajectories.csv"}, "secret", 60).split(".")[0]
    assert verify_payload(f"{forged}.{mac}", "secret") is None
    assert verify_payload("garbage", "secret") is None


def test_signed_payload_expires() -> None:
    signed = sign_payload({"key": "k"}, "secret", expires_s=-1)
    assert verify_payload(signed, "secret") is None
    assert verify_payload(sign_payload({"key": "k"}, "secret", 5), "secret") == {"key": "k"}
