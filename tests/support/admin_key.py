"""The admin key of the suite's service: the in-process app's settings
(``tests/conftest.py``) and the live servers made from them accept it."""

from __future__ import annotations

ADMIN_KEY = "test-admin-key"
