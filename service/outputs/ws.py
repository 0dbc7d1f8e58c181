"""A WebSocket server that sends each pose record as JSON text to every connected client, and serves
a static page drawing the skeleton (``static/index.html``) at ``/`` (the ``websockets`` asyncio API).

Every client has its own bounded queue: when a client is slower than the poses arrive, its oldest
queued record is dropped (and counted), so memory stays bounded and a slow browser shows fresh poses;
the other clients are not affected.  A WebSocket upgrade is accepted on any path; plain HTTP ``GET /``
returns the page, anything else 404.
"""

from __future__ import annotations

import asyncio
import http
import threading
from importlib import resources

INSTALL_HINT = "the WebSocket stream needs websockets >= 13: pip install 'websockets>=13'"
QUEUE_SIZE = 64
_END = object()


def page_html() -> str:
    """The viewer page (package data)."""
    return resources.files("service.outputs").joinpath("static/index.html").read_text(encoding="utf-8")


class _Client:
    def __init__(self, ws, size: int) -> None:
        self.ws = ws
        self.queue: asyncio.Queue = asyncio.Queue(maxsize=size)
        self.dropped = 0

    def offer(self, item) -> bool:
        """Queue ``item``; drop the oldest queued one when full.  Returns False if one was dropped."""
        dropped = False
        while True:
            try:
                self.queue.put_nowait(item)
                return not dropped
            except asyncio.QueueFull:
                self.queue.get_nowait()
                self.dropped += 1
                dropped = True


class PoseHub:
    """Fan-out of JSON texts to WebSocket clients; all methods run on the server's event loop.

    Parameters
    ----------
    queue_size : int
        Records queued per client before its oldest is dropped.
    """

    def __init__(self, queue_size: int = QUEUE_SIZE) -> None:
        if int(queue_size) < 1:
            raise ValueError(f"queue size must be at least 1, got {queue_size}")
        self.queue_size = int(queue_size)
        self.clients: set[_Client] = set()
        self.client_seen = threading.Event()  # set at the first connection (read from any thread)
        self.sent = 0
        self.dropped = 0
        self.finished = False

    def publish(self, text: str) -> None:
        """Queue one record's JSON text for every connected client."""
        self.sent += 1
        for c in list(self.clients):
            if not c.offer(text):
                self.dropped += 1

    def finish(self) -> None:
        """No more records: every client's sender closes its connection after its queue."""
        self.finished = True
        for c in list(self.clients):
            c.offer(_END)

    async def handler(self, ws) -> None:
        """websockets connection handler: send queued records until the end or a disconnect."""
        client = _Client(ws, self.queue_size)
        self.clients.add(client)
        self.client_seen.set()
        if self.finished:
            client.offer(_END)
        try:
            while True:
                item = await client.queue.get()
                if item is _END:
                    await ws.close(1000, "end of stream")
                    return
                await ws.send(item)
        except Exception:  # a client that went away: nothing to do but forget it
            return
        finally:
            self.clients.discard(client)

    async def drain(self, timeout_s: float = 5.0) -> None:
        """Wait (at most ``timeout_s``) until every client has been sent its queue and closed."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s
        while self.clients and loop.time() < end:
            await asyncio.sleep(0.02)


def process_request(connection, request):
    """Serve the page on plain ``GET /``; let WebSocket upgrades (any path) through."""
    if request.headers.get("Upgrade", "").lower() == "websocket":
        return None
    if request.path.split("?")[0] not in ("/", "/index.html"):
        return connection.respond(http.HTTPStatus.NOT_FOUND, "not found\n")
    response = connection.respond(http.HTTPStatus.OK, page_html())
    del response.headers["Content-Type"]
    response.headers["Content-Type"] = "text/html; charset=utf-8"
    response.headers["Cache-Control"] = "no-store"
    return response


async def serve(host: str, port: int, hub: PoseHub, stop: asyncio.Event, *, on_ready=None) -> None:
    """Run the server on ``host:port`` until ``stop`` is set (``on_ready(port)`` once listening)."""
    try:
        from websockets.asyncio.server import serve as ws_serve
    except ImportError:
        raise RuntimeError(INSTALL_HINT) from None
    async with ws_serve(hub.handler, host, port, process_request=process_request, compression=None,
                        write_limit=2**16, max_size=2**16, close_timeout=2) as server:
        bound = server.sockets[0].getsockname()[1] if server.sockets else port
        if on_ready is not None:
            on_ready(bound)
        await stop.wait()
        await hub.drain()


def run_bridge(texts, *, host: str, port: int, stop: threading.Event, queue_size: int = QUEUE_SIZE,
               wait_for_client: bool = False, on_ready=None) -> PoseHub:
    """Serve the page and send every JSON text of ``texts`` to every client, until ``texts`` ends or
    ``stop`` is set; then close the clients after their queues and return the hub (``sent``, ``dropped``).

    Parameters
    ----------
    texts : iterable of str
        Consumed in a worker thread (it may block: a paced replay, a live subscription).
    wait_for_client : bool
        Start consuming ``texts`` only once a first client has connected (a replay).
    on_ready : callable, optional
        Called with the bound port once the server listens.

    Raises
    ------
    OSError
        The address cannot be listened on.
    """
    async def main() -> PoseHub:
        loop = asyncio.get_running_loop()
        hub = PoseHub(queue_size)
        done = asyncio.Event()
        ready = threading.Event()

        def ready_at(bound: int) -> None:
            if on_ready is not None:
                on_ready(bound)
            ready.set()

        server = asyncio.create_task(serve(host, port, hub, done, on_ready=ready_at))

        def produce() -> None:
            try:
                while not ready.wait(0.05):
                    if stop.is_set() or server.done():
                        return
                while wait_for_client and not hub.client_seen.wait(0.1):
                    if stop.is_set():
                        return
                for text in texts:
                    loop.call_soon_threadsafe(hub.publish, text)
                    if stop.is_set():
                        return
            finally:
                loop.call_soon_threadsafe(hub.finish)
                loop.call_soon_threadsafe(done.set)

        producer = loop.run_in_executor(None, produce)
        try:
            await server
        finally:
            stop.set()
            await producer
        return hub

    return asyncio.run(main())
