"""The console's and the docs' pages are served by the api from the package's files."""

from __future__ import annotations

import httpx


async def test_the_service_root_leads_to_the_console(client: httpx.AsyncClient) -> None:
    root = await client.get("/")
    assert root.status_code == 307
    assert root.headers["location"] == "console/"
    page = await client.get("/console/")
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    assert "default-src 'self'" in page.headers["content-security-policy"]


async def test_docs_pages_load_their_assets_from_this_service(client: httpx.AsyncClient) -> None:
    for path, asset in (("/docs", "swagger-ui-bundle.js"), ("/redoc", "redoc.standalone.js")):
        page = await client.get(path)
        assert page.status_code == 200
        assert "/console/static/vendor/" in page.text
        assert asset in page.text
        assert "cdn" not in page.text.lower()
    bundle = await client.get("/console/static/vendor/swagger-ui/swagger-ui-bundle.js")
    assert bundle.status_code == 200
