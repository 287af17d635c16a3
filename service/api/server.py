"""The service in a background thread of this process (``impactcell demo``, tests)."""

from __future__ import annotations

import socket
import threading
import time

from service.api.settings import Settings

__all__ = ["ServerThread", "free_port"]


def free_port(host: str = "127.0.0.1") -> int:
    """A free TCP port on ``host`` (the OS picks it)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class ServerThread:
    """Run the service with uvicorn in a background thread (demo, tests)."""

    def __init__(self, settings: Settings, *, log_level: str = "warning") -> None:
        import uvicorn

        from service.api.app import create_app

        self.settings = settings
        self.port = settings.port or free_port(settings.host)
        config = uvicorn.Config(
            create_app(settings), host=settings.host, port=self.port, log_level=log_level,
            lifespan="on",
        )  # fmt: skip
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, name="impactcell-api", daemon=True)

    @property
    def url(self) -> str:
        """Base URL of the running server."""
        return f"http://{self.settings.host}:{self.port}"

    def start(self, timeout: float = 60.0) -> ServerThread:
        """Start and wait until it accepts requests."""
        self.thread.start()
        t0 = time.monotonic()
        while not self.server.started:
            if not self.thread.is_alive():
                raise RuntimeError("the service did not start (see the log above)")
            if time.monotonic() - t0 > timeout:
                raise RuntimeError(f"the service did not start within {timeout:g} s")
            time.sleep(0.05)
        return self

    def stop(self) -> None:
        """Shut down gracefully (the runner finishes its chunks in flight)."""
        self.server.should_exit = True
        self.thread.join(120)
