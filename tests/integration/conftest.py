"""Integration tests use the shared ``sim`` and ``daemon`` fixtures (lupintest.fixtures)."""
