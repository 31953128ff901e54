"""Running ``graphpos live`` and ``graphpos replay`` as a user does, in subprocesses, for the live tests."""

from __future__ import annotations

import json
import os
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

GRAPHPOS = [sys.executable, "-m", "graphpos"]
#: Longest a live test waits for anything.
TIMEOUT_S = 120.0


class LiveProcess:
    """``graphpos live`` in a subprocess, its stderr lines read in a thread."""

    def __init__(self, *args: str, cwd: Path):
        self.proc = subprocess.Popen([*GRAPHPOS, "live", *args], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.lines: queue.Queue[str] = queue.Queue()
        self.stderr: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.listen = self.wait_for(r"listening on (\S+)").split(",")[0]
        self.foxglove = None
        if "--no-foxglove" not in args:
            self.foxglove = self.wait_for(r"Foxglove: open connection (\S+)")

    def _read(self) -> None:
        for raw in self.proc.stderr:
            line = raw.decode(errors="replace").rstrip("\n")
            self.stderr.append(line)
            self.lines.put(line)

    def wait_for(self, pattern: str) -> str:
        """The first group of the next stderr line matching ``pattern``."""
        deadline = time.monotonic() + TIMEOUT_S
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.5)
            except queue.Empty:
                if self.proc.poll() is not None:
                    raise AssertionError(f"graphpos live exited ({self.proc.returncode}):\n" + "\n".join(self.stderr))
                continue
            found = re.search(pattern, line)
            if found:
                return found.group(1)
        raise AssertionError(f"no line matching {pattern!r}:\n" + "\n".join(self.stderr))

    def result(self) -> tuple[int, dict]:
        """Wait for the exit; (status, the final status JSON it printed)."""
        # stderr is the reader thread's: communicate() reading it too raced the thread for the lines,
        # and closed the pipe under it (a ValueError in the thread)
        stderr, self.proc.stderr = self.proc.stderr, None
        out, _ = self.proc.communicate(timeout=TIMEOUT_S)
        self._reader.join(timeout=TIMEOUT_S)
        stderr.close()
        text = out.decode()
        return self.proc.returncode, (json.loads(text) if text.strip() else {})

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=TIMEOUT_S)


def replay(drive: Path, to: str, *args: str, cwd: Path) -> dict:
    """``graphpos replay DRIVE --to ADDRESS ARGS --json``: the counts it printed."""
    done = subprocess.run([*GRAPHPOS, "replay", str(drive), "--to", to, "--json", *args], cwd=cwd, capture_output=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stderr.decode()
    return json.loads(done.stdout.decode().strip().splitlines()[-1])


class FoxgloveClient:
    """A Foxglove WebSocket client (the ``websockets`` package) in a thread: subscribes to every channel and
    keeps each message, by topic (JSON channels decoded, others raw)."""

    SUBPROTOCOL = "foxglove.sdk.v1"

    def __init__(self, url: str):
        import asyncio

        self.messages: dict[str, list] = {}
        self.encodings: dict[str, str] = {}
        self.schemas: dict[str, str] = {}
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._error: list[BaseException] = []
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run(url)), daemon=True)
        self._thread.start()
        if not self._connected.wait(TIMEOUT_S):
            raise AssertionError(f"could not connect to {url}: {self._error}")

    async def _run(self, url: str) -> None:
        import asyncio
        import struct

        import websockets

        try:
            async with websockets.connect(url, subprotocols=[self.SUBPROTOCOL]) as ws:
                self._connected.set()
                subscribed: dict[int, str] = {}
                next_id = 0
                while not self._stop.is_set():
                    try:
                        frame = await asyncio.wait_for(ws.recv(), 0.2)
                    except asyncio.TimeoutError:
                        continue
                    except websockets.ConnectionClosed:
                        return
                    if isinstance(frame, str):
                        body = json.loads(frame)
                        if body.get("op") == "advertise":
                            subs = []
                            for ch in body["channels"]:
                                subscribed[next_id] = ch["topic"]
                                self.encodings[ch["topic"]] = ch["encoding"]
                                self.schemas[ch["topic"]] = ch["schemaName"]
                                subs.append({"id": next_id, "channelId": ch["id"]})
                                next_id += 1
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        continue
                    if frame[0] != 1:
                        continue
                    sub_id, _log_ns = struct.unpack_from("<IQ", frame, 1)
                    topic = subscribed.get(sub_id)
                    payload = bytes(frame[13:])
                    value = json.loads(payload) if self.encodings.get(topic) == "json" else payload
                    self.messages.setdefault(topic, []).append(value)
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            self._error.append(exc)
            self._connected.set()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(TIMEOUT_S)
