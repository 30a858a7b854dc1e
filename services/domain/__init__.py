"""The service's domain: state machine, workflow, use cases and queries (no HTTP, no Celery).

The API's routers and the worker's tasks call into this package; it raises
`services.domain.errors` and talks to PostgreSQL through `repositories`.
"""
