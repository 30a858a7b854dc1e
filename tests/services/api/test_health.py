"""``/healthz`` and ``/readyz`` against real and unreachable dependencies."""

from __future__ import annotations

from pathlib import Path

from tests.services.conftest import Service, free_port, make_settings


def test_healthz(api_service: Service) -> None:
    response = api_service.client.get("/healthz")
    assert response.status_code == 200 and response.json() == {"status": "ok"}


def test_readyz_with_everything_up(api_service: Service, s3_api_service: Service) -> None:
    for service in (api_service, s3_api_service):
        response = service.client.get("/readyz")
        assert response.status_code == 200, response.text
        assert response.json() == {
            "status": "ok",
            "database": "ok",
            "broker": "ok",
            "storage": "ok",
        }


def test_readyz_names_what_is_down(database_url: str, broker_prefix: str, tmp_path: Path) -> None:
    port = free_port()
    settings = make_settings(
        database_url,
        broker_prefix,
        tmp_path,
        backend="s3",
        s3_endpoint=f"http://127.0.0.1:{port}",
        broker_url=f"redis://127.0.0.1:{port}/0",
    )
    service = Service(settings)
    service.storage.client.meta.config.retries = {"max_attempts": 1}
    response = service.client.get("/readyz")
    assert response.status_code == 503
    body = response.json()
    assert body["status"] == "unavailable" and body["database"] == "ok"
    assert body["broker"].startswith("error: ") and body["storage"].startswith("error: ")
    service.client.close()
