# mocap-index: the web service, on the embedded SQLite database with its data in the /data
# volume, or on PostgreSQL (MOCAP_DATABASE_URL; /data then holds only the index cache).
#   docker compose up --build        (PostgreSQL and two replicas, see docker-compose.yml)
#   docker build -t mocap-index . && docker run -p 8000:8000 -v mocap-data:/data mocap-index
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MOCAP_DATA_DIR=/data \
    MOCAP_HOST=0.0.0.0 \
    MOCAP_PORT=8000

# An unprivileged user owns only the data directory; a new named volume mounted on /data
# takes this ownership.
RUN groupadd --system mocap \
    && useradd --system --gid mocap --no-create-home --home-dir /nonexistent mocap \
    && mkdir /data \
    && chown mocap:mocap /data

WORKDIR /app

# Dependencies (with the postgres extra) first, in their own layer, so a code change does not
# reinstall them.
COPY pyproject.toml README.md ./
RUN python -c "import tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; print('\n'.join(p['dependencies'] + p['optional-dependencies']['postgres']))" > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt \
    && rm /tmp/requirements.txt

# The application. Installed in place (editable) because the Alembic migrations live beside
# app/ in migrations/, where the service looks for them.
COPY alembic.ini ./
COPY migrations ./migrations
COPY app ./app
RUN pip install --no-deps -e . && python -m compileall -q app migrations

USER mocap
VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen(f\"http://127.0.0.1:{os.environ.get('MOCAP_PORT', '8000')}/health\", timeout=4)"]

CMD ["mocap-index", "serve"]
