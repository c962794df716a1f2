"""rotmod's test suite, laid out like the package (tests/response/ tests rotmod.response).

Every folder is a package so that same-named modules in different folders
(tests/io/test_events.py, tests/events/test_events.py) get distinct names under pytest's
default import mode; shared helpers are imported as ``from tests.conftest import rad``.
"""
