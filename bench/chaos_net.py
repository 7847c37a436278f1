"""A TCP relay between two Zenoh routers that can cut the link and heal it: a real network
partition for the chaos campaign (:mod:`bench.chaos`). Router 2 connects to the relay, the
relay to router 1; :meth:`Relay.cut` closes every relayed connection and refuses new ones
(both routers see the link drop at once), :meth:`Relay.heal` accepts again (router 2
reconnects by itself)."""

from __future__ import annotations

import contextlib
import socket
import threading


class Relay:
    """Relays ``127.0.0.1:<port>`` to ``127.0.0.1:<target>`` until cut (see the module
    docstring)."""

    def __init__(self, target: int) -> None:
        self.target = target
        self._lock = threading.Lock()
        self._socks: list[socket.socket] = []
        self._open = True
        self._stop = False
        self._listen = socket.create_server(("127.0.0.1", 0))
        self.port = int(self._listen.getsockname()[1])
        self._thread = threading.Thread(target=self._accept, name="relay", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._stop:
            try:
                conn, _ = self._listen.accept()
            except OSError:
                return
            with self._lock:
                refuse = not self._open
            if refuse:
                conn.close()
                continue
            try:
                up = socket.create_connection(("127.0.0.1", self.target), timeout=2.0)
            except OSError:
                conn.close()
                continue
            up.settimeout(None)
            with self._lock:
                self._socks += [conn, up]
            for a, b in ((conn, up), (up, conn)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
                s.close()

    def cut(self) -> None:
        """Drop every relayed connection and refuse new ones."""
        with self._lock:
            self._open = False
            socks, self._socks = self._socks, []
        for s in socks:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
            s.close()

    def heal(self) -> None:
        """Accept connections again."""
        with self._lock:
            self._open = True

    def close(self) -> None:
        """Stop relaying."""
        self._stop = True
        self.cut()
        self._listen.close()
