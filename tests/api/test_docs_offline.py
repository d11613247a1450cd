"""The OpenAPI browser UI must work on a machine without internet access."""

import re


def test_docs_page_loads_swagger_ui_from_the_service_itself(client):
    page = client.get("/docs")
    assert page.status_code == 200
    assets = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert assets, page.text
    for asset in assets:
        assert not asset.startswith(("http://", "https://", "//")), asset
        if asset.endswith((".js", ".css")):
            fetched = client.get(asset)
            assert fetched.status_code == 200, asset
            assert len(fetched.content) > 10_000, asset


def test_openapi_schema_is_served(client):
    schema = client.get("/openapi.json").json()
    assert {"/clips", "/search", "/descriptors", "/health"} <= set(schema["paths"])
