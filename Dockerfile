# The firefly3d API and worker (one image; docker-compose.yml picks the command).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
RUN useradd --create-home --uid 1000 firefly
WORKDIR /app

# Dependencies first, so that code changes reuse this layer.
COPY pyproject.toml README.md ./
RUN mkdir -p pipeline services && touch pipeline/__init__.py services/__init__.py \
    && pip install '.[service]' && pip uninstall -y firefly3d

COPY pipeline ./pipeline
COPY services ./services
COPY migrations ./migrations
COPY alembic.ini ./
RUN pip install --no-deps '.[service]'

RUN mkdir /work && chown firefly /work
USER firefly
EXPOSE 8000
CMD ["firefly3d", "serve", "--host", "0.0.0.0", "--port", "8000"]
