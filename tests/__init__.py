"""The test suite. A module's tests mirror it: ``tests/<package path>/test_<module>.py``
for ``server/<package path>/<module>.py`` (the service's layers directly under
``tests/``), ``lab/...`` and ``client_sim/...`` (under ``tests/lab`` and
``tests/client_sim``); whole-service tests are in ``tests/e2e`` and ``tests/browser``.
What the tests share is in ``tests.support``, their shared fixtures in the conftest files.
"""

import pytest

# the shared helpers' asserts say what they compared, as the tests' own do
pytest.register_assert_rewrite("tests.support")
