"""docker-compose.yml and the proxy config, checked by reading them (no Docker engine here):
PostgreSQL from the official image with a named volume and a health check, the replicas on
it only once it is healthy, one address in front of them, and settings that exist."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from app.config import Settings
from tests.conftest import REPO_ROOT


def compose() -> dict[str, Any]:
    loaded = yaml.safe_load((REPO_ROOT / "docker-compose.yml").read_text())
    assert isinstance(loaded, dict)
    return loaded


def test_postgres_service() -> None:
    spec = compose()
    postgres = spec["services"]["postgres"]
    assert re.fullmatch(r"postgres:15(\.\d+)?(-\w+)?", postgres["image"])
    volume = postgres["volumes"][0].split(":")
    assert volume[0] in spec["volumes"] and volume[1] == "/var/lib/postgresql/data"
    assert "pg_isready" in " ".join(postgres["healthcheck"]["test"])
    env = postgres["environment"]
    assert {"POSTGRES_USER", "POSTGRES_PASSWORD", "POSTGRES_DB"} <= set(env)


def test_api_replicas_use_the_database() -> None:
    spec = compose()
    api = spec["services"]["api"]
    postgres = spec["services"]["postgres"]["environment"]
    assert api["depends_on"]["postgres"]["condition"] == "service_healthy"
    assert api["deploy"]["replicas"] >= 2
    assert "ports" not in api, "replicas are reached through the proxy only"
    env = api["environment"]
    url = env["MOCAP_DATABASE_URL"]
    assert url.startswith("postgresql+psycopg://")
    assert f"{postgres['POSTGRES_USER']}:" in url and url.endswith(
        f"@postgres:5432/{postgres['POSTGRES_DB']}"
    )
    known = {f"MOCAP_{name.upper()}" for name in Settings.model_fields}
    known.add("FORWARDED_ALLOW_IPS")  # uvicorn's own: trust the proxy's X-Forwarded-For
    assert set(env) <= known, set(env) - known
    assert str(env["MOCAP_PORT"]) in {str(p) for p in api["expose"]}


def test_proxy_in_front_of_the_replicas() -> None:
    spec = compose()
    proxy = spec["services"]["proxy"]
    assert proxy["image"].startswith("nginx:")
    host_port = proxy["ports"][0].rsplit(":", 1)
    source, target = proxy["volumes"][0].split(":")[:2]
    config = (REPO_ROOT / source).read_text()
    assert target.startswith("/etc/nginx/conf.d/")
    port = spec["services"]["api"]["environment"]["MOCAP_PORT"]
    assert re.search(rf"server\s+api:{port}\s+resolve", config)
    assert re.search(rf"listen\s+{host_port[1]};", config)
    assert "proxy_pass http://mocap_api;" in config
    # nginx would refuse uploads the service accepts
    limit = int(spec["services"]["api"]["environment"]["MOCAP_MAX_UPLOAD_BYTES"])
    size = re.search(r"client_max_body_size\s+(\d+)m;", config)
    assert size is not None and int(size.group(1)) * 2**20 > limit
    assert config.count("{") == config.count("}")
    # The service checks Host (port included) and compares it with a write's Origin; the
    # replicas trust X-Forwarded-For, so nginx sets it to the address it saw, nothing more.
    assert "proxy_set_header Host $http_host;" in config
    assert "proxy_set_header X-Forwarded-For $remote_addr;" in config


def test_dockerfile_installs_the_postgres_driver() -> None:
    text = (REPO_ROOT / "Dockerfile").read_text()
    assert "['optional-dependencies']['postgres']" in text
    assert Path(REPO_ROOT / "deploy" / "nginx.conf").is_file()
