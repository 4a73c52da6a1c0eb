"""The emulated head on the wire: a pseudo-terminal (or a TCP port) that a driver opens like the real
serial line, served by a thread that feeds bytes to an :class:`~cistern_archive.acquisition.emulator.EmulatedHead`."""

from __future__ import annotations

import errno
import os
import select
import socket
import threading
import time
import tty

import numpy as np

from cistern_archive.acquisition.echoes import SimulatedEcho
from cistern_archive.acquisition.emulator import EmulatedHead, HeadTiming
from cistern_archive.acquisition.faults import FaultInjector, FaultPlan
from cistern_archive.tritech.stream import StreamDecoder

__all__ = ["EmulatorServer", "build_emulator"]

class EmulatorServer:
    """Serves an :class:`EmulatedHead` on a pty or a TCP port, in a background thread.

    Use :meth:`on_pty` or :meth:`on_tcp`, then :meth:`start` (or ``with``); :attr:`url` is what
    ``serial.serial_for_url`` opens (the pty path, or ``socket://127.0.0.1:PORT``). Output sent while no
    client listens is lost, as on a real serial line.
    """

    def __init__(self, head: EmulatedHead, injector: FaultInjector):
        self.head = head
        self.injector = injector
        self.url = ""
        self.bytes_in = 0
        self.bytes_out = 0
        self._stop = threading.Event()
        self._closing = threading.Lock()
        self._thread: threading.Thread | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._listener: socket.socket | None = None
        self._client: socket.socket | None = None
        self._decoder = StreamDecoder()
        self._t0 = time.monotonic()
        self.error: BaseException | None = None

    @classmethod
    def on_pty(cls, head: EmulatedHead, injector: FaultInjector) -> "EmulatorServer":
        """A pseudo-terminal in raw mode; :attr:`url` is the slave's path (e.g. ``/dev/pts/3``)."""
        server = cls(head, injector)
        master, slave = os.openpty()
        tty.setraw(slave)
        tty.setraw(master)
        os.set_blocking(master, False)
        server._master, server._slave = master, slave
        server.url = os.ttyname(slave)
        return server

    @classmethod
    def on_tcp(cls, head: EmulatedHead, injector: FaultInjector, *, host: str = "127.0.0.1",
               port: int = 0) -> "EmulatorServer":
        """A TCP listener (one client at a time); :attr:`url` is ``socket://HOST:PORT``."""
        server = cls(head, injector)
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind((host, port))
        listener.listen(1)
        listener.setblocking(False)
        server._listener = listener
        server.url = f"socket://{host}:{listener.getsockname()[1]}"
        return server

    # lifecycle -----------------------------------------------------------------------------------

    def start(self) -> "EmulatorServer":
        self._thread = threading.Thread(target=self.serve_forever, name="sonar-head-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the line; safe to call again and from several threads at once.

        Each descriptor is taken under a lock before it is closed, so it is closed exactly once: a
        second close would hit whatever file the process opened under that number since.
        """
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        with self._closing:
            fds, self._master, self._slave = (self._master, self._slave), None, None
            socks, self._client, self._listener = (self._client, self._listener), None, None
        for fd in fds:
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        for sock in socks:
            if sock is not None:
                sock.close()

    def __enter__(self) -> "EmulatorServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def now(self) -> float:
        return time.monotonic() - self._t0

    def serve_forever(self) -> None:
        """Run until :meth:`stop` (or KeyboardInterrupt in the calling thread)."""
        try:
            while not self._stop.is_set():
                self._step(min(0.05, self.head.next_event(self.now())))
        except BaseException as exc:  # recorded for the caller; the thread must not die silently
            self.error = exc
            raise

    # I/O -----------------------------------------------------------------------------------------

    def _readable(self) -> list:
        if self._master is not None:
            return [self._master]
        assert self._listener is not None
        return [self._client if self._client is not None else self._listener]

    def _step(self, timeout: float) -> None:
        ready, _, _ = select.select(self._readable(), [], [], timeout)
        now = self.now()
        for source in ready:
            if source is self._listener:
                self._accept()
            else:
                self._receive(self._read(source), now)
        for data in self.head.poll(now):
            self._send(data)

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            client, _ = self._listener.accept()
        except BlockingIOError:
            return
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._client = client
        self._decoder = StreamDecoder()

    def _read(self, source) -> bytes:
        try:
            if isinstance(source, socket.socket):
                data = source.recv(4096)
                if not data:
                    self._drop_client()
                return data
            return os.read(source, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as exc:
            if isinstance(source, socket.socket):
                self._drop_client()
                return b""
            if exc.errno == errno.EIO:
                return b""
            raise

    def _drop_client(self) -> None:
        if self._client is not None:
            self._client.close()
        self._client = None

    def _receive(self, data: bytes, now: float) -> None:
        self.bytes_in += len(data)
        for packet in self._decoder.feed(data):
            for out in self.head.handle(packet, now):
                self._send(out)
        self._decoder.take_discards()

    def _send(self, data: bytes) -> None:
        wire = self.injector(data)
        try:
            if self._master is not None:
                view = memoryview(wire)
                deadline = time.monotonic() + 0.05  # nobody reading: the rest is lost, as on a real line
                while view and time.monotonic() < deadline:
                    try:
                        view = view[os.write(self._master, view):]
                    except BlockingIOError:
                        if self._stop.wait(0.002):
                            return
                self.bytes_out += len(wire) - len(view)
            elif self._client is not None:
                self._client.sendall(wire)
                self.bytes_out += len(wire)
        except OSError:
            self._drop_client()


def build_emulator(echo: SimulatedEcho, *, faults: FaultPlan = FaultPlan(), tcp_port: int | None = None,
                   host: str = "127.0.0.1", timing: HeadTiming | None = None,
                   half_duplex: bool = False, keep_history: bool = False) -> EmulatorServer:
    """A ready (not yet started) emulator: pty when ``tcp_port`` is None, else TCP (0 = any free port).

    The head's noise and the wire's faults use two generators derived from ``faults.seed``.
    """
    head = EmulatedHead(echo, np.random.default_rng([faults.seed, 0]), faults=faults, timing=timing,
                        half_duplex=half_duplex, keep_history=keep_history)
    injector = FaultInjector(faults, np.random.default_rng([faults.seed, 1]))
    if tcp_port is None:
        return EmulatorServer.on_pty(head, injector)
    return EmulatorServer.on_tcp(head, injector, host=host, port=tcp_port)
