"""The HTTP/WebSocket API of SPEC §5: aiohttp app, OpenAPI document, metrics and security.

The API is a thin skin over :class:`lupin.services.Services`: it validates
bodies with the pydantic models of :mod:`lupin.api_models`, calls one service
method per endpoint, and turns every refusal into a 4xx error body. It never
talks to the bus itself.
"""

from __future__ import annotations

from lupin.api.server import ApiServer, build_app

__all__ = ["ApiServer", "build_app"]
