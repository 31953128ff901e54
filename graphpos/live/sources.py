"""Where live messages come from: UDP datagrams or TCP lines, each handed on with its receipt time.

An address is ``udp://HOST:PORT`` or ``tcp://HOST:PORT`` (port 0: any free
port, told by :attr:`Listener.address`). Each listener runs in its own
thread and does nothing but receive, so that a busy estimator never makes
the kernel drop a datagram: the receipt time is taken when the message is
read (for UDP, the kernel's own receive stamp, ``SO_TIMESTAMPNS``, so that
a read delayed by a busy interpreter does not hide latency).
"""

from __future__ import annotations

import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable

from graphpos.errors import ConfigError

#: (payload, receipt time in ns since the epoch, where it came from)
Sink = Callable[[bytes, int, str], None]

#: Receive buffer asked for on UDP sockets: about 20 s of a 100 Hz IMU with every other sensor.
UDP_BUFFER_BYTES = 32 * 1024 * 1024
#: Linux's SO_RCVBUFFORCE (beyond net.core.rmem_max, for a privileged process): Python's socket module names it
#: only from 3.12 on, and without it a 3.11 receiver got the kernel's cap (8 MB here, under 2 s of a 20-times-fast
#: replay) and lost readings, the end of the drive among them, while its estimators caught up.
_SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33 if sys.platform.startswith("linux") else None)
#: Longest TCP line accepted; a longer one is cut off and handed on (it is then malformed).
MAX_LINE_BYTES = 65536
_POLL_S = 0.2
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)


@dataclass(frozen=True)
class Address:
    """A parsed ``udp://HOST:PORT`` or ``tcp://HOST:PORT``."""

    scheme: str
    host: str
    port: int

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}"

    @classmethod
    def parse(cls, text: str, schemes: tuple[str, ...] = ("udp", "tcp")) -> "Address":
        """The address in ``text``; ConfigError (one line) for anything else."""
        scheme, sep, rest = text.partition("://")
        if not sep or scheme not in schemes:
            raise ConfigError(f"address {text!r} must look like {' or '.join(s + '://HOST:PORT' for s in schemes)}")
        host, _, port = rest.rpartition(":")
        host = host.strip("[]")
        if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ConfigError(f"address {text!r}: expected HOST:PORT with a port from 0 to 65535")
        return cls(scheme, host, int(port))


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


class Listener:
    """Receives on one address in a thread and hands every message to ``sink``.

    Raises
    ------
    ConfigError
        The address cannot be bound (in use, not this machine's).
    """

    def __init__(self, address: Address, sink: Sink):
        self._sink = sink
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        try:
            if address.scheme == "udp":
                self._sock = socket.socket(_family(address.host), socket.SOCK_DGRAM)
                self._big_buffer()
                self._sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
            else:
                self._sock = socket.socket(_family(address.host), socket.SOCK_STREAM)
                self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((address.host, address.port))
            if address.scheme == "tcp":
                self._sock.listen(8)
        except OSError as exc:
            raise ConfigError(f"cannot listen on {address}: {exc.strerror or exc}") from None
        self._sock.settimeout(_POLL_S)
        host, port = self._sock.getsockname()[:2]
        self.address = Address(address.scheme, host, port)
        target = self._receive_udp if address.scheme == "udp" else self._accept_tcp
        self._spawn(target)

    def _big_buffer(self) -> None:
        for option in (_SO_RCVBUFFORCE, socket.SO_RCVBUF):
            if option is None:
                continue
            try:
                self._sock.setsockopt(socket.SOL_SOCKET, option, UDP_BUFFER_BYTES)
                return
            except OSError:
                continue  # not allowed (SO_RCVBUFFORCE needs privileges): the kernel's cap applies

    def _spawn(self, target, *args) -> None:
        thread = threading.Thread(target=target, args=args, name=f"graphpos-live-{target.__name__}", daemon=True)
        self._threads.append(thread)
        thread.start()

    def _receive_udp(self) -> None:
        where = str(self.address)
        while not self._stop.is_set():
            try:
                payload, ancillary, _, _ = self._sock.recvmsg(MAX_LINE_BYTES, 64)
            except TimeoutError:
                continue
            except OSError:
                return  # closed
            receipt_ns = time.time_ns()
            for level, kind, data in ancillary:
                if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= 16:
                    sec, nsec = struct.unpack("qq", data[:16])
                    receipt_ns = sec * 1_000_000_000 + nsec
            self._sink(payload, receipt_ns, where)

    def _accept_tcp(self) -> None:
        while not self._stop.is_set():
            try:
                conn, peer = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.settimeout(_POLL_S)
            self._spawn(self._read_lines, conn, f"tcp://{peer[0]}:{peer[1]}")

    def _read_lines(self, conn: socket.socket, where: str) -> None:
        pending = b""
        with conn:
            while not self._stop.is_set():
                try:
                    data = conn.recv(1 << 16)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not data:
                    break
                receipt_ns = time.time_ns()
                pending += data
                *lines, pending = pending.split(b"\n")
                if len(pending) > MAX_LINE_BYTES:
                    lines.append(pending)
                    pending = b""
                for line in lines:
                    if line.strip():
                        self._sink(line, receipt_ns, where)
            if pending.strip():
                self._sink(pending, time.time_ns(), where)

    def close(self) -> None:
        """Stop receiving (what was received has been handed on)."""
        self._stop.set()
        self._sock.close()
        for thread in self._threads:
            thread.join(timeout=2 * _POLL_S + 1)


def sender(address: Address) -> Callable[[bytes], None]:
    """A function that sends one message to ``address`` (a datagram, or a line on one TCP connection).

    Raises
    ------
    ConfigError
        Nothing listens there (TCP), or the host is unknown.
    """
    try:
        if address.scheme == "udp":
            sock = socket.socket(_family(address.host), socket.SOCK_DGRAM)
            sock.connect((address.host, address.port))
            return sock.send
        sock = socket.create_connection((address.host, address.port), timeout=10)
        sock.settimeout(None)
    except OSError as exc:
        raise ConfigError(f"cannot send to {address}: {exc.strerror or exc}") from None
    return lambda payload: sock.sendall(payload + b"\n")
