"""API tests: the HTTP/WebSocket API against the real daemon on the simulated bus."""
