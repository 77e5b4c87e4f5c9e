"""A real HTTP receiver on 127.0.0.1 for apprise's json:// posts: what the alert tests send to (never a mock of
the sender). The ``receiver`` fixture in conftest starts one per test on a free port and stops it after."""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

SECRET = "s3cr3t-token"  # the URL's token: tests check it stays out of journals, logs and command lines


class Receiver:
    """Every post as its JSON body plus the ``path`` it came to; ``url`` is the apprise URL that reaches it."""

    def __init__(self) -> None:
        got: list[dict[str, object]] = []

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                got.append({"path": self.path, **json.loads(body or b"{}")})
                self.send_response(200)
                self.end_headers()

            def log_message(self, *args: object) -> None:
                pass

        self.got = got
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    @property
    def url(self) -> str:
        return f"json://127.0.0.1:{self.port}/{SECRET}"

    def bodies(self) -> list[str]:
        """The messages received, in order."""
        return [str(m.get("message", "")) for m in self.got]

    def of(self, kind: str) -> list[str]:
        """The messages of one apprise type (``info``, ``success``, ``warning``, ``failure``)."""
        return [str(m.get("message", "")) for m in self.got if m.get("type") == kind]
