"""Test helpers of the dashboard: HTTP requests and a server-sent-events reader."""
from __future__ import annotations

import http.client as httpclient
import json
import threading
import urllib.error
import urllib.request
from typing import Any
from urllib.parse import urlsplit

from helpers.waiting import DEFAULT_TIMEOUT_S as TIMEOUT


def http(url: str, body: Any = None, *, content_type: str = "application/json",
         headers: dict[str, str] | None = None, raw: bytes | None = None) -> tuple[int, Any]:
    """GET (no body) or POST ``body`` as JSON; returns (status, decoded JSON or text)."""
    data = raw if raw is not None else None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, method="GET" if data is None else "POST",
                                     headers={**({"Content-Type": content_type} if data is not None else {}),
                                              **(headers or {})})
    try:
        with urllib.request.urlopen(request, timeout=TIMEOUT) as response:
            status, payload = response.status, response.read()
    except urllib.error.HTTPError as exc:
        status, payload = exc.code, exc.read()
    try:
        return status, json.loads(payload)
    except ValueError:
        return status, payload.decode("utf-8", "replace")


class EventStream:
    """Reads ``GET /api/events`` in a thread; ``events`` is every ``(kind, data)`` received."""

    def __init__(self, base_url: str) -> None:
        parts = urlsplit(base_url)
        self._conn = httpclient.HTTPConnection(parts.hostname, parts.port, timeout=TIMEOUT)
        self._conn.request("GET", "/api/events")
        self._response = self._conn.getresponse()
        assert self._response.status == 200
        assert self._response.getheader("Content-Type").startswith("text/event-stream")
        self.events: list[tuple[str, dict[str, Any]]] = []
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        kind, data = None, []
        try:
            for raw in self._response:
                line = raw.decode().rstrip("\n")
                if line.startswith("event: "):
                    kind = line[7:]
                elif line.startswith("data: "):
                    data.append(line[6:])
                elif not line and kind is not None:
                    with self._lock:
                        self.events.append((kind, json.loads("\n".join(data))))
                    kind, data = None, []
        except (OSError, ValueError, AttributeError, httpclient.HTTPException):  # ended or closed
            pass

    def of(self, kind: str) -> list[dict[str, Any]]:
        with self._lock:
            return [d for k, d in self.events if k == kind]

    @property
    def ended(self) -> bool:
        return not self._thread.is_alive()

    def close(self) -> None:
        self._conn.close()
        self._thread.join(timeout=10.0)
