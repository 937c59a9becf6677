"""How messages travel on a stream: 4 bytes of length (big-endian), then the message.

Bounded both ways: a screen's message is at most MAX_IN bytes (a command, a comment), a
runtime's at most MAX_OUT (a frame with a first frame's whole history)."""

from __future__ import annotations

import socket

HEADER = 4
MAX_IN = 256 * 1024
MAX_OUT = 64 * 1024 * 1024


def frame(data: bytes) -> bytes:
    return len(data).to_bytes(HEADER, "big") + data


def recv_exactly(sock: socket.socket, size: int) -> bytes:
    chunks = []
    while size:
        chunk = sock.recv(min(size, 1 << 20))
        if not chunk:
            raise ConnectionError("the connection closed")
        chunks.append(chunk)
        size -= len(chunk)
    return b"".join(chunks)


def read_message(sock: socket.socket, most: int) -> bytes:
    """One message from a blocking socket; ConnectionError at its end or if it is longer
    than `most` bytes."""
    size = int.from_bytes(recv_exactly(sock, HEADER), "big")
    if not 0 < size <= most:
        raise ConnectionError(f"a message of {size} bytes (at most {most})")
    return recv_exactly(sock, size)
