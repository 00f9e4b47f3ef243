"""The one test harness every test module shares.

- ``TOKEN``: the operator token every server and DecisionServer under test is given.
- ``waiting``: ``until`` (and ``until_async``), the one poll-with-a-deadline.
- ``servers``: ``serving``, the one way to start ``telerobot serve`` (its URL is always
  ``http://127.0.0.1:PORT/``), and ``telerobot`` for the other commands.
- ``browser``: Debian's Chromium (one per test session: the ``browser`` fixture in
  tests/conftest.py) and the operator page's helpers.
- ``clock``: ``run_with_clock``, virtual time for async work.

Test modules import from here, from harness/ (what the benchmarks share with the
tests: server starters, the link emulator, clients) and from the product, never from
each other; neither harness/ nor bench/ imports anything from tests/.
"""

from tests.support.waiting import until, until_async

TOKEN = "operator-token-for-tests-0123456789"

__all__ = ["TOKEN", "until", "until_async"]
